"""Copy each saved results table into its generated block of the README or the docs.

    python -m benchmarks.sync_docs

Every table of measured results in the README and the docs sits between ``<!-- name:start -->`` and
``<!-- name:end -->`` and is exactly its results file (``tests/test_readme.py`` checks it); run this
after a benchmark rewrote one.
"""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"

#: (block name, results file under benchmarks/results) of every generated table
GENERATED_BLOCKS = [
    ("bench", "pareto/summary.md"),
    ("calibration", "calibration_summary.md"),
    ("calibration-methods", "calibration_methods.md"),
    ("fit-measured", "fit_measured.md"),
    ("fit-photos", "fit_photos.md"),
    ("fit-image-tones", "fit_image_tones.md"),
    ("renderers", "renderers.md"),
    ("layered-renders", "layered_renders.md"),
    ("face-blur", "face_blur.md"),
    ("forward-model", "forward_model.md"),
    ("fit-image", "fit_image.md"),
    ("transport-fit", "transport_fit.md"),
    ("fit-realistic", "fit_realistic.md"),
    ("profile-fits", "profile_fits.md"),
]


def pages() -> list[Path]:
    """The README and the docs pages."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def main() -> int:
    changed = []
    for marker, results_file in GENERATED_BLOCKS:
        table = (RESULTS / results_file).read_text(encoding="utf-8").strip()
        start, end = f"<!-- {marker}:start -->\n", f"\n<!-- {marker}:end -->"
        for page in pages():
            text = page.read_text(encoding="utf-8")
            if start not in text:
                continue
            head, rest = text.split(start, 1)
            new = head + start + table + end + rest.split(end, 1)[1]
            if new != text:
                page.write_text(new, encoding="utf-8")
                changed.append(f"{page.relative_to(ROOT)} ({marker})")
    print("updated: " + (", ".join(changed) if changed else "nothing"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
