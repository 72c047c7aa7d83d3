"""What the user sees of the library's log lines when a command runs.

Library modules log (`log = logging.getLogger(__name__)`) and commands print their results:
the commands' entry points call `show_progress` once, so that segmin's progress lines (INFO)
and everyone's warnings reach stderr as bare messages, while other libraries' INFO lines
(onnxscript's optimisation passes, ...) stay quiet.
"""

from __future__ import annotations

import logging

PACKAGE = "segmin"


def show_progress() -> None:
    """segmin's INFO lines and every warning on stderr, message only (once per process: a second
    call, or a host that set up logging itself, such as pytest, keeps the handlers it has)."""
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    logging.getLogger(PACKAGE).setLevel(logging.INFO)
