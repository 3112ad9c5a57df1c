"""Writing a matplotlib figure to disk, shared by the plotting modules of every layer (design §2)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402


def save_figure(fig, out_png: str | Path, dpi: int = 110) -> Path:
    """Lay out ``fig``, write it to ``out_png`` (creating the folder) and close it; returns the path."""
    fig.tight_layout()
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out
