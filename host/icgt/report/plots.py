"""The report's figures, drawn with matplotlib (Agg) and returned as inline SVG text.

Every axis names its unit. Times are seconds from the recording's first message; positions are
metres in the recording's ENU frame; footprints are in the structure face's map coordinates (s
along the face, t up it; `icgt.geometry.plane_axes`).
"""

from __future__ import annotations

import io
import math
from collections import Counter
from typing import Any

import numpy as np

from icgt.geotag.record import FrameRecord
from icgt.report.summary import PLAUSIBLE_RADIUS_M, FlightData

OK_COLOUR = "#1f77b4"
FLAG_COLOUR = "#d62728"
_FLAG_ROWS_MAX = 10
_TRACK_POINTS_MAX = 5000


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    matplotlib.rcParams["svg.fonttype"] = "none"  # text stays text: smaller, selectable
    matplotlib.rcParams["svg.hashsalt"] = "icgt"  # the same recording gives the same page
    matplotlib.rcParams["font.size"] = 9
    import matplotlib.pyplot as plt

    return plt


def _svg(fig: Any) -> str:
    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight", metadata={"Date": None})
    _plt().close(fig)
    text = buf.getvalue()
    return text[text.index("<svg") :]  # drop the XML prolog and DOCTYPE: the SVG goes inline in HTML


def _plausible(r: FrameRecord) -> bool | None:
    """Is the frame's position inside the plausible area (None: it has no position)?"""
    if r.east_m is None or r.north_m is None or r.up_m is None:
        return None
    return math.hypot(r.east_m, r.north_m, r.up_m) <= PLAUSIBLE_RADIUS_M


def frames_outside(data: FlightData) -> int:
    """Frames with a position outside the plausible area (not drawn)."""
    return sum(1 for r in data.frames if _plausible(r) is False)


def _frame_xyz(data: FlightData) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any]]:
    """(positions (N, 3) ENU [m] of frames that have one inside the plausible area, flagged mask)."""
    rows = [(r.east_m, r.north_m, r.up_m, bool(r.flags)) for r in data.frames if _plausible(r)]
    if not rows:
        return np.zeros((0, 3)), np.zeros(0, dtype=bool)
    arr = np.array([r[:3] for r in rows], dtype=float)
    return arr, np.array([r[3] for r in rows])


def track_figure(data: FlightData) -> str:
    """Plan view and elevation of the vehicle track with the frame positions."""
    return _svg(track_axes(data)[0])


def track_axes(data: FlightData) -> tuple[Any, Any, Any]:
    """(figure, plan axes, elevation axes) of `track_figure`, drawn but not yet rendered."""
    plt = _plt()
    fig, (plan, elev) = plt.subplots(1, 2, figsize=(11, 4.2))
    track = data.track_enu_m
    if len(track) > _TRACK_POINTS_MAX:  # an hour at 50 Hz would make a 5 MB page: every k-th sample is enough
        track = track[:: -(-len(track) // _TRACK_POINTS_MAX)]
    pos, flagged = _frame_xyz(data)
    if len(track):
        plan.plot(track[:, 0], track[:, 1], "-", color="#888", lw=1, label="vehicle track (GLOBAL_POSITION_INT)")
    for mask, colour, label in ((~flagged, OK_COLOUR, "frame"), (flagged, FLAG_COLOUR, "frame with flags")):
        if mask.any():
            plan.plot(pos[mask, 0], pos[mask, 1], "o", ms=4, color=colour, label=label)
    plan.set_xlabel("east [m]")
    plan.set_ylabel("north [m]")
    plan.set_title("plan view")
    plan.set_aspect("equal", adjustable="datalim")
    plan.grid(alpha=0.3)
    # elevation along the track's main horizontal direction
    both = np.vstack([track[:, :2], pos[:, :2]]) if len(track) or len(pos) else np.zeros((0, 2))
    axis = np.array([1.0, 0.0])
    if len(both) > 2:
        centred = both - both.mean(axis=0)
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        axis = vt[0] if np.linalg.norm(vt[0]) > 0 else axis
    if len(track):
        elev.plot(track[:, :2] @ axis, track[:, 2], "-", color="#888", lw=1)
    for mask, colour in ((~flagged, OK_COLOUR), (flagged, FLAG_COLOUR)):
        if mask.any():
            elev.plot(pos[mask, :2] @ axis, pos[mask, 2], "o", ms=4, color=colour)
    elev.set_xlabel(f"along ({axis[0]:.2f} E, {axis[1]:.2f} N) [m]")
    elev.set_ylabel("up [m]")
    elev.set_title("elevation")
    elev.set_aspect("equal", adjustable="datalim")
    elev.grid(alpha=0.3)
    if plan.get_legend_handles_labels()[0]:
        plan.legend(loc="best", fontsize=8)
    return fig, plan, elev


def coverage_grid(
    footprints: list[np.ndarray[Any, Any]], cells: int = 240
) -> tuple[np.ndarray[Any, Any], tuple[float, float, float, float]]:
    """How many footprints cover each cell of a grid over their extent: (counts (rows, cols), extent)."""
    from matplotlib.path import Path as MplPath

    allpts = np.vstack(footprints)
    s0, t0 = allpts.min(axis=0)
    s1, t1 = allpts.max(axis=0)
    span = max(s1 - s0, t1 - t0, 1e-6)
    step = span / cells
    ss = np.arange(s0 + step / 2, s1, step)
    ts = np.arange(t0 + step / 2, t1, step)
    grid = np.stack(np.meshgrid(ss, ts), axis=-1).reshape(-1, 2)
    counts = np.zeros(len(grid), dtype=np.int32)
    for fp in footprints:
        counts += MplPath(fp).contains_points(grid)
    return counts.reshape(len(ts), len(ss)), (float(s0), float(s1), float(t0), float(t1))


def footprint_figure(data: FlightData) -> str | None:
    """The footprints on the structure face, shaded by how many images cover each place."""
    if not data.footprints:
        return None
    plt = _plt()
    fps = list(data.footprints.values())
    counts, extent = coverage_grid(fps)
    fig, ax = plt.subplots(figsize=(11, 5))
    masked = np.ma.masked_equal(counts, 0)
    im = ax.imshow(masked, origin="lower", extent=extent, cmap="viridis", interpolation="nearest", aspect="equal")
    for fp in fps:
        ring = np.vstack([fp, fp[:1]])
        ax.plot(ring[:, 0], ring[:, 1], "-", color="white", lw=0.4, alpha=0.7)
    fig.colorbar(im, ax=ax, label="images covering [count]", shrink=0.8)
    ax.set_xlabel("s, along the face [m]")
    ax.set_ylabel("t, up the face [m]")
    ax.set_title(f"footprints on the structure face ({len(fps)} frames)")
    return _svg(fig)


def timeline_figure(data: FlightData) -> str:
    """Capture, flags, link outages and losses against time."""
    plt = _plt()
    flags: Counter[str] = Counter(f for r in data.frames for f in r.flags)
    rows = ["exposures"] + [f for f, _ in flags.most_common(_FLAG_ROWS_MAX)] + ["device link", "autopilot link"]
    fig, ax = plt.subplots(figsize=(11, 0.9 + 0.32 * len(rows)))
    y = {name: i for i, name in enumerate(reversed(rows))}
    t = np.array([data.t_s(r.mid_host_ns) for r in data.frames])
    flagged = np.array([bool(r.flags) for r in data.frames])
    if len(t):
        ax.scatter(t[~flagged], np.full((~flagged).sum(), y["exposures"]), marker="|", s=120, color=OK_COLOUR)
        ax.scatter(t[flagged], np.full(flagged.sum(), y["exposures"]), marker="|", s=120, color=FLAG_COLOUR)
    for name in rows[1:-2]:
        tt = [data.t_s(r.mid_host_ns) for r in data.frames if name in r.flags]
        ax.scatter(tt, [y[name]] * len(tt), marker="|", s=120, color=FLAG_COLOUR)
    for o in data.outages:
        row = y["device link" if o.link == "device" else "autopilot link"]
        ax.barh(row, o.end_s - o.start_s, left=o.start_s, height=0.6, color="#ff7f0e")
    for loss in data.losses:
        row = y["device link" if loss.link == "device" else "autopilot link"]
        ax.plot([loss.t_s], [row], "x", color="black", ms=6)
    ax.set_yticks(list(y.values()), list(y.keys()))
    ax.set_xlim(0, max(data.duration_s, 1e-3))
    ax.set_xlabel("time from the first message [s]")
    ax.set_title("capture timeline: exposures, flags (red), outages (orange bars), losses (x)")
    ax.grid(axis="x", alpha=0.3)
    return _svg(fig)


def clock_figure(data: FlightData) -> str:
    """The device->host mapping bound and the UTC bound over time (log scale, us)."""
    plt = _plt()
    fig, (dev, utc) = plt.subplots(1, 2, figsize=(11, 3.6))
    ct = [t for t, b in data.device_clock if b is not None]
    cb = [b for _, b in data.device_clock if b is not None]
    if ct:
        dev.plot(ct, cb, "-", color="#888", label="clock filter estimate")
    ft = [data.t_s(r.mid_host_ns) for r in data.frames]
    fb = [max(r.mid_host_uncertainty_ns / 1000.0, 1e-3) for r in data.frames]
    if ft:
        dev.plot(ft, fb, "o", ms=3, color=OK_COLOUR, label="at each exposure")
    dev.set_yscale("log")
    dev.set_xlabel("time [s]")
    dev.set_ylabel("device->host bound [us]")
    dev.set_title("device clock")
    dev.grid(alpha=0.3, which="both")
    if dev.get_legend_handles_labels()[0]:
        dev.legend(fontsize=8)
    by_source: dict[str, tuple[list[float], list[float]]] = {}
    for t, b, s in data.utc_clock:
        if b is not None:
            by_source.setdefault(s or "?", ([], []))
            by_source[s or "?"][0].append(t)
            by_source[s or "?"][1].append(max(b, 1e-3))
    for source, (tt, bb) in by_source.items():
        utc.plot(tt, bb, ".-", ms=3, label=f"estimate ({source})")
    ut = [data.t_s(r.mid_host_ns) for r in data.frames if r.mid_utc_uncertainty_us is not None]
    ub = [max(float(r.mid_utc_uncertainty_us), 1e-3) for r in data.frames if r.mid_utc_uncertainty_us is not None]
    if ut:
        utc.plot(ut, ub, "o", ms=3, color=OK_COLOUR, label="at each exposure")
    utc.set_yscale("log")
    utc.set_xlabel("time [s]")
    utc.set_ylabel("UTC bound [us]")
    utc.set_title("UTC")
    utc.grid(alpha=0.3, which="both")
    if utc.get_legend_handles_labels()[0]:
        utc.legend(fontsize=8)
    return _svg(fig)


def quality_figure(data: FlightData) -> str:
    """Geotag quality per frame: GPS accuracies, pose gaps, range, predicted blur."""
    plt = _plt()
    fig, axes = plt.subplots(2, 2, figsize=(11, 5.4), sharex=True)
    t = np.array([data.t_s(r.mid_host_ns) for r in data.frames])

    def col(name: str) -> np.ndarray[Any, Any]:
        return np.array([np.nan if getattr(r, name) is None else float(getattr(r, name)) for r in data.frames])

    panels = (
        (axes[0, 0], (("h_acc_m", "horizontal"), ("v_acc_m", "vertical")), "GPS accuracy [m]"),
        (axes[0, 1], (("pose_gap_before_ms", "before"), ("pose_gap_after_ms", "after")), "pose sample gap [ms]"),
        (axes[1, 0], (("range_m", "LiDAR range"),), "range [m]"),
        (axes[1, 1], (("blur_px", "predicted blur"),), "blur [px]"),
    )
    for ax, series, label in panels:
        for name, what in series:
            v = col(name)
            v[~np.isfinite(v)] = np.nan
            if len(t):
                ax.plot(t, v, "o-", ms=3, lw=0.8, label=what)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if len(series) > 1 and ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    fig.suptitle("geotag quality at each exposure")
    return _svg(fig)
