"""Where the running code came from: the git commit of segmin's own source checkout, if any.

Exported models and reports record it. It is asked only of the checkout that holds segmin's
source (an editable install); an installed wheel has none, and the folder a user happens to run
in is never asked (its repository is not ours).
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import segmin


def source_checkout() -> Path | None:
    """The repository root of an editable install (the folder above `segmin/` with .git and pyproject.toml)."""
    root = Path(segmin.__file__).resolve().parents[1]
    if (root / ".git").exists() and (root / "pyproject.toml").is_file():
        return root
    return None


def git_commit() -> str:
    """segmin's source commit, or "unknown" for an installed wheel or without git."""
    root = source_checkout()
    if root is None:
        return "unknown"
    try:
        result = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=5, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    commit = result.stdout.strip()
    return commit if result.returncode == 0 and commit else "unknown"
