"""The one way the project draws a PNG: matplotlib on the file-only Agg backend.

matplotlib is imported on first use, so nodes and tools that never plot do not pay for it at
start-up. No ROS import.
"""

from __future__ import annotations

import os
from pathlib import Path
from types import ModuleType
from typing import Any


def pyplot() -> ModuleType:
    """``matplotlib.pyplot`` with the Agg backend (no display needed)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 90) -> Path:
    """Lay the figure out tightly, write it to ``path``, free it, and return the path."""
    out = Path(path)
    fig.tight_layout()
    fig.savefig(out, dpi=dpi)
    pyplot().close(fig)
    return out
