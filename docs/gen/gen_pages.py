"""mkdocs-gen-files script: writes the generated reference pages into the build (never into
the repository). The pages themselves are made by ``reference.py`` next to this file."""

from __future__ import annotations

import sys
from pathlib import Path

import mkdocs_gen_files

sys.path.insert(0, str(Path(__file__).resolve().parent))

import reference

for path, text in reference.pages().items():
    with mkdocs_gen_files.open(path, "w") as f:
        f.write(text)
with mkdocs_gen_files.open("reference/SUMMARY.md", "w") as f:
    f.write(reference.reference_nav())
