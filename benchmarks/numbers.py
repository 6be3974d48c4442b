"""Every number in the README and the documentation, and where it comes from.

    python -m benchmarks.numbers            # writes benchmarks/results/numbers.md, prints the summary
    python -m benchmarks.numbers --orphans  # also prints every number with no source

Each number (a run of digits, with its decimals and exponent) in ``README.md`` and ``docs/*.md`` is
classified by where it stands:

- ``generated``: inside a ``<!-- name:start -->`` ... ``<!-- name:end -->`` block, which the tests keep
  equal to its results file (``tests/test_readme.py``);
- ``sourced``: in a paragraph that names its results files in a ``<!-- source: benchmarks/results/F ... -->``
  comment, and found in one of them (to the precision shown); a named source that does not hold the
  number is a ``mismatch``;
- ``code``: in code (commands, examples, inputs), not a result;
- ``one-off``: in a paragraph marked "One-off observation" with its date: a figure no script
  reproduces, kept as what it is;
- ``definition``: listed in a ``<!-- defines: 400 700 10 -->`` comment of its paragraph: an input, a
  setting, a threshold, a bound, a version or a constant of a formula, which the text defines rather
  than reports (a listed number that the paragraph does not hold is a ``mismatch``: the mark is stale);
- ``reference``: a citation (year, volume, pages, DOI), a figure quoted beside a link to the model notes, or
  a section of the model notes, which carry
  their sources inline (``docs/model-notes.md`` is the model's reference notes);
- ``orphan``: none of these. A published figure should become generated or sourced, be marked as a
  one-off observation with its date, or be marked as a definition. The listing names a results file
  that holds an equal value (to the precision shown, two significant digits or more) as a candidate
  source: a hint, not an attribution (a results file with thousands of values matches almost
  anything).
"""

from __future__ import annotations

import argparse
import json
import re
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:[.,]\d+)*(?:\.\d+)?(?:e[-+]?\d+)?(?![\d.,]\d)", re.I)
CITATION = re.compile(r"(DOI|doi\.org|SIGGRAPH|EGSR|Phys\. Med|Opt\. Lett|Scientific Data|Color Res|Photochem|"
                      r"OMLC|https?://|et al\.|model-notes\.md\)|\(\d{4}\)|\b(19|20)\d{2}\b|\bIEC |\bISO |\bITU)")


def _values(node, out: list[float]) -> list[float]:
    """Every number in a JSON tree (strings parsed where they are numbers)."""
    if isinstance(node, dict):
        for v in node.values():
            _values(v, out)
    elif isinstance(node, list):
        for v in node:
            _values(v, out)
    elif isinstance(node, bool):
        pass
    elif isinstance(node, (int, float)):
        out.append(float(node))
    elif isinstance(node, str):
        out.extend(float(m) for m in re.findall(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", node, re.I)[:50])
    return out


def _results() -> dict[str, list[float]]:
    files = {}
    for path in sorted(RESULTS.rglob("*")):
        if path.name == "numbers.md":  # this census's own output
            continue
        if path.suffix == ".json":
            files[str(path.relative_to(ROOT))] = _values(json.loads(path.read_text()), [])
        elif path.suffix in (".md", ".csv"):
            files[str(path.relative_to(ROOT))] = [float(m) for m in NUMBER.findall(path.read_text().replace(",", " "))
                                                   if _parse(m) is not None]
    return files


def _parse(text: str) -> float | None:
    try:
        return float(text.replace(",", ""))
    except ValueError:
        return None


def _significant(shown: str) -> int:
    digits = re.sub(r"e.*$", "", shown.lower()).replace(",", "").replace(".", "").lstrip("+-").lstrip("0")
    return len(digits.rstrip("0")) if "." not in shown else len(digits)


def _holds(values: list[float], shown: str, strict: bool = True) -> bool:
    """A value that rounds to the number as shown (also scaled to %, ms or us); a number
    of one significant digit (3, 0.5, 100) matches too much to say anything: it holds only where
    the paragraph names its source (``strict=False``)."""
    x = _parse(shown)
    if x is None or (strict and _significant(shown) < 2):
        return False
    decimals = len(shown.split(".")[1].split("e")[0]) if "." in shown else 0
    tolerance = 0.5 * 10.0 ** (-decimals) * (1 + 1e-9)
    if "e" in shown.lower():  # half a unit of the mantissa's last digit
        tolerance *= 10.0 ** int(shown.lower().split("e")[1])
    for v in values:
        for scaled in (v, 100 * v, v / 100, 1e3 * v, 1e6 * v, v / 1e3):  # also as %, ms, us (and us as ms)
            if abs(scaled - x) <= tolerance:
                return True
    return False


def _paragraphs(lines: list[str]) -> list[int]:
    """The paragraph index of each line (a blank line, a list item or a heading starts one)."""
    index, out = 0, []
    for line in lines:
        if not line.strip() or re.match(r"^\s*([-*] |\d+\. |#)", line):
            index += 1
        out.append(index)
    return out


def classify(path: Path, results: dict[str, list[float]]) -> list[tuple[int, str, str, str]]:
    """(line, number, class, source) for every number of ``path``."""
    found = []
    fenced = False
    block = None
    model_notes = path.name == "model-notes.md"
    lines = path.read_text().splitlines()
    paragraph = _paragraphs(lines)
    sources, one_off, defines, first_line = {}, set(), {}, {}
    for k, line in enumerate(lines):
        first_line.setdefault(paragraph[k], k + 1)
        named = re.search(r"<!-- source: ([^>]+?) -->", line)
        if named:
            sources[paragraph[k]] = named.group(1).split()
        for listed in re.findall(r"<!-- defines: ([^>]+?) -->", line):
            defines.setdefault(paragraph[k], Counter()).update(listed.split())
        if "one-off" in line.lower():  # "*One-off observation (date, ...)*", possibly broken over lines
            one_off.add(paragraph[k])
    for i, line in enumerate(lines, 1):
        source = sources.get(paragraph[i - 1])
        if line.strip().startswith("```"):
            fenced = not fenced
            continue
        start = re.search(r"<!-- ([\w-]+):start -->", line)
        if start:
            block = start.group(1)
        if re.search(r"<!-- [\w-]+:end -->", line):
            block = None
            continue
        text = re.sub(r"<!--.*?-->", "", line)
        code_spans = [m.span() for m in re.finditer(r"`[^`]*`", text)]
        for m in NUMBER.finditer(text):
            shown = m.group(0)
            in_code = fenced or any(a <= m.start() < b for a, b in code_spans)
            if block:
                kind, where = "generated", block
            elif in_code:
                kind, where = "code", ""
            elif model_notes or CITATION.search(text[max(0, m.start() - 60): m.end() + 20]) or re.match(r"^#+ ", text):
                kind, where = "reference", ""
            elif paragraph[i - 1] in one_off:
                kind, where = "one-off", ""
            elif defines.get(paragraph[i - 1], Counter())[shown] > 0:
                defines[paragraph[i - 1]][shown] -= 1  # each listed entry defines one occurrence
                kind, where = "definition", ""
            elif source:
                values = [v for name in source for v in results.get(name, [])]
                kind, where = ("sourced", " ".join(source)) if _holds(values, shown, strict=False) else ("mismatch", " ".join(source))
            else:
                holders = [f for f, values in results.items() if _holds(values, shown)]
                kind, where = "orphan", (f"candidate {holders[0]}" if holders else "")
            found.append((i, shown, kind, where))
    for index, left in defines.items():  # listed but not in the paragraph: a stale mark
        found += [(first_line[index], shown, "mismatch", "defines") for shown, n in left.items() for _ in range(n)]
    return found


def _listing(page, line, shown, kind, where) -> str:
    return f"{page}:{line}: {shown} ({kind}{', ' + where if where else ''})"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--orphans", action="store_true", help="print every number with no source")
    parser.add_argument("--out", default=str(RESULTS / "numbers.md"))
    args = parser.parse_args(argv)
    results = _results()
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    rows, orphans = [], []
    total = Counter()
    for page in pages:
        entries = classify(page, results)
        counts = Counter(kind for _, _, kind, _ in entries)
        total += counts
        rows.append((page.relative_to(ROOT), counts))
        orphans += [(page.relative_to(ROOT), line, shown, kind, where) for line, shown, kind, where in entries
                    if kind in ("orphan", "mismatch")]
    kinds = ("generated", "sourced", "one-off", "definition", "code", "reference", "mismatch", "orphan")
    lines = ["| page | " + " | ".join(kinds) + " |", "|---|" + "---|" * len(kinds)]
    lines += [f"| {page} | " + " | ".join(str(c[k]) for k in kinds) + " |" for page, c in rows]
    lines += ["| all | " + " | ".join(str(total[k]) for k in kinds) + " |"]
    text = "\n".join(lines) + "\n\n" + "\n".join("- " + _listing(*entry) for entry in orphans) + "\n"
    Path(args.out).write_text("# Numbers in the README and docs, by source (python -m benchmarks.numbers)\n\n" + text)
    print("\n".join(lines))
    if args.orphans:
        for entry in orphans:
            print(_listing(*entry))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
