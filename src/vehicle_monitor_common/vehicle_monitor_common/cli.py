"""What every command-line tool of the project does the same way with a failure.

An expected failure (a bad configuration, a missing or unreadable file) is the user's to fix:
one line ``error: ...`` on stderr and exit status 2, no traceback. Ctrl-C ends with 130, as
a shell reports a command ended by SIGINT. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

from collections.abc import Callable
import sys

ExceptionTypes = tuple[type[BaseException], ...]


def run_cli(body: Callable[[], int], errors: ExceptionTypes,
            interrupts: ExceptionTypes = (KeyboardInterrupt,)) -> int:
    """``body()``'s exit status; 2 after printing one of ``errors``, 130 on an interrupt."""
    try:
        return body()
    except errors as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    except interrupts:
        return 130
