"""Corner-style figure of a pose posterior (matplotlib, Agg): the edge where plots live.

Diagonal: weighted marginals of x, y and heading (degrees); below it: weighted 2-D
histograms of each pair. Mode means are marked, the true pose (if known) drawn as lines.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from localization.posterior import PosteriorResult
from mapping.angles import wrap_angle

LABELS = ("x (m)", "y (m)", "heading (deg)")


def _columns(result: PosteriorResult) -> NDArray[np.float64]:
    """Samples with heading in degrees, unwrapped about the heaviest mode's heading."""
    pts = result.samples.copy()
    c = result.modes[0].mean[2]
    pts[:, 2] = np.degrees(c + wrap_angle(pts[:, 2] - c))
    return pts


def corner_figure(result: PosteriorResult, truth: NDArray[np.float64] | None = None,
                  title: str = "", bins: int = 40) -> plt.Figure:
    """A 3 x 3 corner plot of ``result`` (weighted by mode mass)."""
    pts = _columns(result)
    w = result.weights
    c = result.modes[0].mean[2]
    marks = np.array([[m.mean[0], m.mean[1],
                       math.degrees(c + float(wrap_angle(m.mean[2] - c)))] for m in result.modes])
    tr = None
    if truth is not None and np.all(np.isfinite(truth)):
        tr = np.array([truth[0], truth[1], math.degrees(c + float(wrap_angle(truth[2] - c)))])
    lo = np.minimum(pts.min(axis=0), tr if tr is not None else np.inf)
    hi = np.maximum(pts.max(axis=0), tr if tr is not None else -np.inf)
    pad = 0.05 * np.maximum(hi - lo, 1e-6)
    ranges = list(zip(lo - pad, hi + pad, strict=True))
    fig, axes = plt.subplots(3, 3, figsize=(8.5, 8.5))
    for i in range(3):
        for j in range(3):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(pts[:, i], bins=bins, range=ranges[i], weights=w, color="C0",
                        histtype="stepfilled", alpha=0.7)
                ax.set_yticks([])
                if tr is not None:
                    ax.axvline(tr[i], color="k", lw=1)
            else:
                ax.hist2d(pts[:, j], pts[:, i], bins=bins, range=[ranges[j], ranges[i]],
                          weights=w, cmap="Blues")
                ax.plot(marks[:, j], marks[:, i], "r+", ms=10)
                if tr is not None:
                    ax.axvline(tr[j], color="k", lw=0.8)
                    ax.axhline(tr[i], color="k", lw=0.8)
                    ax.plot(tr[j], tr[i], "ks", ms=4)
            if i == 2:
                ax.set_xlabel(LABELS[j])
            if j == 0 and i > 0:
                ax.set_ylabel(LABELS[i])
    lines = [title] if title else []
    for k, m in enumerate(result.modes):
        lines.append(
            f"mode {k}: mass {m.mass:.2f}, sd x {math.sqrt(m.cov[0, 0]) * 100:.1f} cm, "
            f"y {math.sqrt(m.cov[1, 1]) * 100:.1f} cm, heading "
            f"{math.degrees(m.heading_circular_std_rad):.1f} deg; tau {np.max(m.tau):.0f}, "
            f"acc {m.acceptance_fraction:.2f}, {'converged' if m.converged else 'NOT converged'}")
    fig.text(0.40, 0.985, "\n".join(lines), va="top", ha="left", fontsize=7.5)
    fig.tight_layout(rect=(0, 0, 1, 0.9))
    return fig


def write_corner_png(path: Path, result: PosteriorResult,
                     truth: NDArray[np.float64] | None = None, title: str = "") -> None:
    """Render :func:`corner_figure` to ``path`` (PNG, 110 dpi)."""
    fig = corner_figure(result, truth, title)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.png")
    try:
        fig.savefig(tmp, dpi=110)
        tmp.replace(path)
    finally:
        plt.close(fig)
        if tmp.exists():
            tmp.unlink()
