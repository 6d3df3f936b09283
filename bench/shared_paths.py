"""Where the bench scripts find the project's ``shared`` folder (the real IFCs, the oracles).

One rule for every script, the same as the tests' (``tests/conftest.py``): ``$BIMCAP_SHARED``
when set; else ``../shared`` beside the checkout; from a git worktree (whose ``.git`` is a file
naming ``<main>/.git/worktrees/<name>``), the one beside the main checkout.
"""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def shared_dir() -> Path:
    """The ``shared`` folder; the first candidate when none exists (the caller says it is
    missing, naming that path)."""
    env = os.environ.get("BIMCAP_SHARED")
    if env:
        return Path(env)
    candidates = [REPO.parent / "shared"]
    dot_git = REPO / ".git"
    if dot_git.is_file():
        text = dot_git.read_text(encoding="utf-8").strip()
        if text.startswith("gitdir:"):
            main = Path(text.partition(":")[2].strip()).resolve().parents[2]
            candidates.append(main.parent / "shared")
    return next((c for c in candidates if c.is_dir()), candidates[0])


def shared_ifc_dir() -> Path:
    """``<shared>/data/ifc``: the real IFC models."""
    return shared_dir() / "data" / "ifc"
