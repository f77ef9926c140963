"""The repeat-inspection scenario pair: the same face (the plane north = 10 m of synth_logs) inspected twice,
on different flight lines and with different GPS biases, with cracks that grow, appear, are repaired or fall
outside the second flight's view.

Each flight's detections are what its camera saw from its TRUE positions (the projector of the project
casting three pixels of each image onto the true face: the image-to-face map, which is affine for this
fronto-parallel camera); its log records the positions with the flight's GPS bias added, so the map places
every defect shifted by that bias, as a real GPS would.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import synth_logs as sl

from icgt.geodesy import LocalFrame
from icgt.geotag import FrameRecord

CARD_W, CARD_H = CAL_W, CAL_H = 1280, 960  # 2.3 mm/px on the face at 2 m
MARGIN_PX = 2.0
PIXEL_NOISE_PX = 0.5
"""The detector's localisation error of a point, 1 sigma [card px] (seeded: the same detections every run)."""


@dataclass(frozen=True)
class Crack:
    name: str
    before: tuple[tuple[float, float], ...] | None
    """The polyline (east, up) [m] on the true face in the first inspection (None: not there yet)."""
    after: tuple[tuple[float, float], ...] | None
    width_mm: float = 0.3
    truth: str = "unchanged"
    """The change a comparison must find: unchanged, grown, new, repaired or not_seen."""

    @staticmethod
    def length_mm(line: tuple[tuple[float, float], ...] | None) -> float:
        if line is None:
            return 0.0
        return 1000.0 * sum(math.dist(a, b) for a, b in itertools.pairwise(line))


def _extend(line: tuple[tuple[float, float], ...], by_m: float) -> tuple[tuple[float, float], ...]:
    (x0, y0), (x1, y1) = line[-2], line[-1]
    d = math.dist(line[-2], line[-1])
    return (*line[:-1], (x1 + (x1 - x0) / d * by_m, y1 + (y1 - y0) / d * by_m))


_C2 = ((2.0, 3.5), (2.25, 3.6))
_C3 = ((3.0, 3.0), (3.05, 3.3))
_C6 = ((0.6, 3.35), (0.8, 3.3))
CRACKS = (
    Crack("unchanged", ((1.0, 3.2), (1.3, 3.25)), ((1.0, 3.2), (1.3, 3.25))),
    Crack("grown-60", _C2, _extend(_C2, 0.060), truth="grown"),
    Crack("grown-120", _C3, _extend(_C3, 0.120), width_mm=0.5, truth="grown"),
    Crack("grown-8", _C6, _extend(_C6, 0.008), truth="grown"),
    Crack("repaired", ((3.8, 3.6), (4.1, 3.55)), None, truth="repaired"),
    Crack("new", None, ((1.6, 3.9), (1.7, 4.2)), truth="new"),
    Crack("unseen", ((2.6, 2.15), (2.9, 2.2)), ((2.6, 2.15), (2.9, 2.2)), truth="not_seen"),
)


@dataclass(frozen=True)
class Inspection:
    synth: sl.Synth
    """The TRUE flight line."""
    bias_m: tuple[float, float]
    """GPS bias (east, up) [m]: logged position minus true."""
    which: str
    """before or after (which polyline of each crack is on the face)."""


BEFORE = Inspection(sl.Synth(seed=1, recording_id=0x2025, calibration_px=(CAL_W, CAL_H)), (0.0, 0.0), "before")
AFTER = Inspection(
    sl.Synth(seed=2, recording_id=0x2026, start_utc=sl.datetime(2026, 6, 2, 10, 0, tzinfo=sl.UTC), shift_east_m=0.1,
             shift_up_m=0.6, calibration_px=(CAL_W, CAL_H)),
    (0.35, -0.12), "after",
)  # fmt: skip


def _image_to_face(rec: FrameRecord, projector: object) -> np.ndarray:
    """The 2x3 affine map from calibration pixels (u, v, 1) to the true face's (east, up) [m]."""
    px = np.array([[0.0, 0.0], [CAL_W, 0.0], [0.0, CAL_H]])
    w = projector.pixel_to_world(rec, px[:, 0], px[:, 1])  # type: ignore[attr-defined]
    eu = np.asarray(w.enu)[:, [0, 2]]
    a = np.c_[px, np.ones(3)]
    return np.linalg.solve(a, eu).T


def detections(insp: Inspection, true_frames: list[FrameRecord], camera: object) -> dict[str, list[dict[str, object]]]:
    """Per card image, the cracks wholly inside it (2 px margin), in card pixels."""
    from icgt.geometry import Plane, Projector

    proj = Projector(camera, origin=LocalFrame(*sl.ORIGIN), structure=Plane((0.0, sl.FACE_NORTH_M, 0.0),
                     (0.0, -1.0, 0.0)), anchor="range")  # type: ignore[arg-type]  # fmt: skip
    out: dict[str, list[dict[str, object]]] = {}
    rng = np.random.default_rng(insp.synth.seed)
    for k, rec in enumerate(true_frames, start=1):
        if rec.lat_deg is None:
            continue
        m = _image_to_face(rec, proj)
        inv = np.linalg.inv(np.vstack([m, [0.0, 0.0, 1.0]]))
        gsd_m = float(np.hypot(m[0, 0], m[1, 0])) * CAL_W / CARD_W  # metres per card pixel
        found = []
        for c in CRACKS:
            line = c.before if insp.which == "before" else c.after
            if line is None:
                continue
            uv = (inv @ np.c_[np.asarray(line), np.ones(len(line))].T)[:2].T * (CARD_W / CAL_W)
            inside = (uv[:, 0] > MARGIN_PX) & (uv[:, 0] < CARD_W - MARGIN_PX)
            inside &= (uv[:, 1] > MARGIN_PX) & (uv[:, 1] < CARD_H - MARGIN_PX)
            if inside.all():
                uv = uv + rng.normal(0.0, PIXEL_NOISE_PX, uv.shape)
                found.append({"kind": "crack", "points_px": uv.round(4).tolist(),
                              "width_px": c.width_mm / 1000.0 / gsd_m, "score": 0.9})  # fmt: skip
        if found:
            out[f"DSC{k:05d}.JPG"] = found
    return out


def write_inspection(folder: Path, insp: Inspection) -> tuple[Path, Path, Path]:
    """(log, card, detections) of one inspection: the log with the biased positions."""
    from icgt.export.cli import camera_from_metadata
    from icgt.ingest import read

    folder.mkdir(parents=True, exist_ok=True)
    true = sl.frames(insp.synth)
    logged_synth = replace(insp.synth, shift_east_m=insp.synth.shift_east_m + insp.bias_m[0],
                           shift_up_m=insp.synth.shift_up_m + insp.bias_m[1])  # fmt: skip
    log = folder / "flight.mcap"
    recs = sl.write_log(log, logged_synth)
    camera = camera_from_metadata(read(log).metadata)
    card = folder / "card"
    sl.write_card(card, recs, size=(CARD_W, CARD_H))
    det = folder / "detections.json"
    det.write_text(json.dumps({"format": "icgt-detections", "images": detections(insp, true, camera)}))
    return log, card, det
