"""mkdocs hook: publish the benchmark charts with the site.

The charts live beside the benchmark scripts that write them, outside ``docs/``; this hook
adds them to the site at the same relative path (``benchmarks/results/NAME.png``), so the
docs link them as ``benchmarks/results/NAME.png`` from ``docs/`` and ``--strict`` checks
every link.
"""

from __future__ import annotations

from pathlib import Path

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[2]


def on_files(files: Files, config) -> Files:  # noqa: ANN001 - mkdocs hook signature
    for png in sorted((ROOT / "benchmarks" / "results").glob("*.png")):
        uri = f"benchmarks/results/{png.name}"
        if files.get_file_from_path(uri) is None:
            files.append(File.generated(config, uri, abs_src_path=str(png)))
    return files
