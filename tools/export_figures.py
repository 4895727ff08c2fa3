"""Execute chapters headless and write every figure they draw as a PNG, to look at them.

    python tools/export_figures.py course/07_bspline_surfaces.ipynb [...] [--out build/figures]

Writes `<out>/<chapter>/cell<NN>_<k>.png` (NN: the cell's index in the notebook) and
`<out>/<chapter>/outputs.md`, the chapter's text outputs in order (Markdown outputs, such as
tables, as their Markdown) with warnings and errors marked, to read every sentence against what
the chapter prints.
"""

from __future__ import annotations

import argparse
import base64
import sys
import tempfile
from pathlib import Path

import diffnurbs_course as dc

ROOT = Path(__file__).resolve().parents[1]


def export(path: Path, out: Path) -> list[str]:
    """Execute `path`, write its figures and text outputs under `out / path.stem`; return
    the problems (error and stderr outputs)."""
    nb = dc.read_notebook(path)
    with tempfile.TemporaryDirectory() as work:
        seconds = dc.execute_notebook(nb, Path(work), timeout=900, allow_errors=True)
    folder = out / path.stem
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("cell*.png"):
        old.unlink()
    lines, problems = [f"# {path.name}: outputs ({seconds:.0f} s)", ""], []
    for index, cell in enumerate(nb.cells):
        if cell.cell_type != "code":
            continue
        tags = cell.metadata.get("tags", [])
        lines.append(f"## cell {index}" + (f" ({', '.join(tags)})" if tags else ""))
        for k, output in enumerate(cell.get("outputs", [])):
            data = output.get("data", {})
            if "image/png" in data:
                name = f"cell{index:02d}_{k}.png"
                (folder / name).write_bytes(base64.b64decode(data["image/png"]))
                lines.append(f"[figure {name}]")
            if output.output_type == "error":
                problems.append(f"cell {index}: {output.ename}: {output.evalue}")
                lines.append(f"**ERROR** {output.ename}: {output.evalue}")
            elif output.output_type == "stream":
                if output.name == "stderr":
                    problems.append(f"cell {index}: stderr: {output.text.strip()[:200]}")
                    lines.append("**STDERR**")
                lines.append(output.text.rstrip())
            elif "text/markdown" in data:
                lines.append(data["text/markdown"].rstrip())
            elif "text/plain" in data and "image/png" not in data:
                lines.append(data["text/plain"].rstrip())
        lines.append("")
    (folder / "outputs.md").write_text("\n".join(lines) + "\n")
    return problems


def main(argv: list[str] | None = None) -> int:
    """Export every chapter given; return 1 if any printed an error or a warning."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("chapters", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, default=ROOT / "build" / "figures")
    args = parser.parse_args(argv)
    failed = False
    for path in args.chapters:
        problems = export(path.resolve(), args.out)
        print(f"{path}: {args.out / path.stem}", *problems, sep="\n  ")
        failed |= bool(problems)
    return int(failed)


if __name__ == "__main__":
    sys.exit(main())
