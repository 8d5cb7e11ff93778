"""mkdocs-gen-files script: writes the generated reference pages into the build (never into
the repository). The pages themselves are made by ``reference.py`` next to this file."""

from __future__ import annotations

import sys
from pathlib import Path

import mkdocs_gen_files
from mkdocs.structure.files import InclusionLevel

sys.path.insert(0, str(Path(__file__).resolve().parent))

import reference

for path, text in reference.pages().items():
    with mkdocs_gen_files.open(path, "w") as f:
        f.write(text)
with mkdocs_gen_files.open("reference/SUMMARY.md", "w") as f:
    f.write(reference.reference_nav())

# the Reference section's navigation is read by literate-nav, not published as a page
# (docs/SUMMARY.md is kept out the same way, by mkdocs.yml's exclude_docs)
nav_file = mkdocs_gen_files.FilesEditor.current().files.get_file_from_path("reference/SUMMARY.md")
if nav_file is not None:
    nav_file.inclusion = InclusionLevel.EXCLUDED
