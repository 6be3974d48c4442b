"""Every number in the README and the documentation, and where it comes from.

    python -m benchmarks.numbers            # writes benchmarks/results/numbers.md, prints the summary
    python -m benchmarks.numbers --orphans  # also prints every number with no source

The rule the docs follow: **a measured figure's paragraph names the command that measured it**, in
the prose (``python -m benchmarks.fit_noise``, or ``python -m benchmarks`` for the Pareto and stress
sweeps), or stands in a block generated from a results file. Nothing else is marked: inputs,
settings, thresholds, versions and names carry no annotation. Each number (a run of digits, with its
decimals and exponent) in ``README.md`` and ``docs/*.md`` is classified by where it stands:

- ``generated``: inside a ``<!-- name:start -->`` ... ``<!-- name:end -->`` block, which the tests keep
  equal to its results file (``tests/test_readme.py``);
- ``sourced``: in a paragraph that names a benchmark command (or a results file, or a list item under
  a paragraph that does), and found in the results files that command writes (to the precision
  shown); a number the named results do not hold is an ``orphan`` "not in" them (a setting beside
  a measured figure, or a figure that is wrong: the listing is for a maintainer to read);
- ``code``: in code (commands, examples, inputs), not a result;
- ``one-off``: in a paragraph marked "One-off observation" with its date: a figure no script
  reproduces, kept as what it is;
- ``name``: a version or a number in a name ("Python 3.11", "Mitsuba 3", "Table 3");
- ``reference``: a citation (year, volume, pages, DOI), a figure quoted beside a link to the model notes, or
  a section of the model notes, which carry
  their sources inline (``docs/model-notes.md`` is the model's reference notes);
- ``orphan``: none of these: a definition (an input, a setting, a bound) or a published figure whose
  paragraph does not say what measured it. The listing names a results file that holds an equal
  value (to the precision shown, two significant digits or more) as a candidate source: a hint, not
  an attribution (a results file with thousands of values matches almost anything).
"""

from __future__ import annotations

import argparse
import json
import re
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
COMMAND = re.compile(r"python -m (benchmarks(?:\.\w+)?)\b")
RESULTS_PATH = re.compile(r"benchmarks/results/[\w./-]+\.(?:json|csv|md)")
# a number that is part of a name: after a capitalised word (Mitsuba 3, Table 3, Python 3.11, Blender 4.2.23)
NAME_BEFORE = re.compile(r"\b[A-Z][A-Za-z]*(?:-v)? $")
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
    sources, one_off = _sources(lines, paragraph, results), set()
    for k, line in enumerate(lines):
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
            elif _is_name(text, m):
                kind, where = "name", ""
            elif source:
                values = [v for name in source for v in results.get(name, [])]
                kind, where = ("sourced", " ".join(source)) if _holds(values, shown, strict=False) else \
                    ("orphan", "not in " + " ".join(source))
            else:
                holders = [f for f, values in results.items() if _holds(values, shown)]
                kind, where = "orphan", (f"candidate {holders[0]}" if holders else "")
            found.append((i, shown, kind, where))
    return found


def _is_name(text: str, m: re.Match) -> bool:
    """A version or a number in a name: an integer or a dotted version right after a capitalised word."""
    shown = m.group(0)
    return bool(re.fullmatch(r"\d+|\d+\.\d+(?:\.\d+)?", shown)) and bool(NAME_BEFORE.search(text[:m.start()])) \
        and not re.match(r"\s*(%|x\b|×|nm|mm|µs|us|ms|s\b)", text[m.end():])


def _script_results(command: str, results: dict[str, list[float]]) -> list[str]:
    """The results files that ``python -m <command>`` writes."""
    from benchmarks.stale import DEPENDS_ON

    if command == "benchmarks":  # the Pareto and stress sweeps
        return [name for name in results if name.startswith("benchmarks/results/pareto/")]
    script = command.replace(".", "/") + ".py"
    return [f"benchmarks/results/{name}" for name, (writer, _) in DEPENDS_ON.items() if writer == script] + \
        [name for name in results if Path(name).stem == command.split(".")[-1]]


def _sources(lines: list[str], paragraph: list[int], results) -> dict[int, list[str]]:
    """Per paragraph, the results files it names: through the benchmark commands or results paths in its
    prose (or a ``<!-- source: ... -->`` comment); a list item that names none has those of the paragraph
    that introduces its list."""
    named: dict[int, list[str]] = {}
    for k, line in enumerate(lines):
        found = [f for c in COMMAND.findall(line) for f in _script_results(c, results)] + RESULTS_PATH.findall(line)
        comment = re.search(r"<!-- source: ([^>]+?) -->", line)
        found += comment.group(1).split() if comment else []
        if found:
            named.setdefault(paragraph[k], []).extend(f for f in found if f not in named.get(paragraph[k], []))
    out, lead = {}, []
    seen = set()
    for k, line in enumerate(lines):
        index = paragraph[k]
        if index in seen or not line.strip():  # a paragraph is read from its first line with text
            continue
        seen.add(index)
        item = re.match(r"^\s*([-*] |\d+\. )", line)
        if re.match(r"^#", line):
            lead = []
        elif not item:
            lead = named.get(index, [])
        mine = named.get(index) or (lead if item else [])
        if mine:
            out[index] = mine
    return out


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
                    if kind == "orphan"]
    kinds = ("generated", "sourced", "one-off", "name", "code", "reference", "orphan")
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
