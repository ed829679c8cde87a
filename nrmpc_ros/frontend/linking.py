"""Landmarks across holds: one id for one 3D point, from KLT identity or descriptors, verified per camera.

A track that KLT follows from one hold through the move into the next keeps
its landmark id. Where too few tracks of a camera survived the move (a jump,
a snapshot, a fast move), the camera's features of the new hold are matched
to those of the camera's previous hold by descriptor (taken at each track's
position in its hold's anchor frame), and a matched track takes over the
landmark id of its partner. Every link between the two holds, from either
source, must fit one essential matrix of that camera (the camera moves
rigidly between two holds even though its bar bends): a track that does
not gets a new landmark id. Landmarks are per camera.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from ..cameras import pixels_to_bearings
from ..core.rig import Rig
from .holds import Hold
from .tracking import Features, TrackingConfig, describe, match_features, verify_correspondences


@dataclass
class _CameraHistory:
    """A camera's latest hold: landmark ids, averaged pixels, bearings and descriptors."""

    landmark: np.ndarray
    uv: np.ndarray
    f: np.ndarray
    desc: np.ndarray | None
    valid: np.ndarray


@dataclass
class HoldObservations:
    """The observations a hold adds to the sequence: camera, landmark id and bearing of each."""

    cam: np.ndarray
    landmark: np.ndarray
    f: np.ndarray
    links: Counter  # per kind: klt, descriptor, rejected (failed the essential-matrix check)


class HoldLinker:
    """Assigns landmark ids to the tracks of successive holds (see the module docstring)."""

    def __init__(self, rig: Rig, cfg: TrackingConfig):
        self.rig = rig
        self.cfg = cfg
        self.reset()

    def reset(self) -> None:
        self._alias = [{} for _ in self.rig.cameras]  # per camera: tracker id -> landmark id
        self._history: list = [None] * self.rig.num_cameras
        self._next = 0

    def _new_ids(self, n: int) -> np.ndarray:
        out = self._next + np.arange(n, dtype=np.int64)
        self._next += n
        return out

    def link(self, hold: Hold) -> HoldObservations:
        cams, lms, fs = [], [], []
        links = Counter()
        for i, ch in enumerate(hold.cameras):
            if ch is None:
                continue
            cam = self.rig.cameras[i]
            alias = self._alias[i]
            use_klt = self.cfg.mode != "descriptors"
            lm = np.array([alias.get(int(k), -1) if use_klt else -1 for k in ch.ids], dtype=np.int64)
            fresh = lm < 0
            lm[fresh] = self._new_ids(int(fresh.sum()))
            f = pixels_to_bearings(cam, ch.uv)
            img = hold.anchor_images[i] if i < len(hold.anchor_images) else None
            desc, valid = describe(img, ch.anchor_uv, self.cfg) if img is not None else (None, np.zeros(len(lm), bool))
            prev = self._history[i]
            if prev is not None:
                lm = self._link_to(prev, cam, lm, f, ch.uv, desc, valid, links)
            lm = _unique_per_hold(lm, self._new_ids)
            alias.update(zip(ch.ids.tolist(), lm.tolist()))
            self._history[i] = _CameraHistory(lm, ch.uv, f, desc, valid)
            cams.append(np.full(len(lm), i, np.int64))
            lms.append(lm)
            fs.append(f)
        if not cams:
            return HoldObservations(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), links)
        return HoldObservations(np.concatenate(cams), np.concatenate(lms), np.concatenate(fs), links)

    def _link_to(self, prev: _CameraHistory, cam, lm, f, uv, desc, valid, links: Counter) -> np.ndarray:
        """Landmark ids of this hold's tracks after verifying and completing the links to the previous hold."""
        cfg = self.cfg
        _, ip, ic = np.intersect1d(prev.landmark, lm, assume_unique=False, return_indices=True)
        cand_p, cand_c = [ip], [ic]
        kinds = [np.zeros(len(ip), bool)]  # False: KLT link, True: descriptor link
        if cfg.mode != "klt" and len(ip) < cfg.min_klt_links and desc is not None and prev.desc is not None:
            free = np.setdiff1d(np.flatnonzero(valid), ic)
            taken = np.zeros(len(prev.landmark), bool)
            taken[ip] = True
            pv = np.flatnonzero(prev.valid & ~taken)
            if len(free) >= 2 and len(pv) >= 2:
                ia, ib = match_features(Features(prev.uv[pv], prev.desc[pv]), Features(uv[free], desc[free]), cfg)
                cand_p.append(pv[ia])
                cand_c.append(free[ib])
                kinds.append(np.ones(len(ia), bool))
        p = np.concatenate(cand_p)
        c = np.concatenate(cand_c)
        by_desc = np.concatenate(kinds)
        if len(p) == 0:
            return lm
        ok = verify_correspondences(cam, prev.f[p], f[c], cfg)
        out = lm.copy()
        bad_klt = c[~ok & ~by_desc]
        out[bad_klt] = self._new_ids(len(bad_klt))  # a track that drifted off its landmark starts a new one
        good_desc = ok & by_desc
        out[c[good_desc]] = prev.landmark[p[good_desc]]
        links["klt"] += int(np.count_nonzero(ok & ~by_desc))
        links["descriptor"] += int(np.count_nonzero(good_desc))
        links["rejected"] += int(np.count_nonzero(~ok))
        return out


def _unique_per_hold(lm: np.ndarray, new_ids) -> np.ndarray:
    """A landmark once per camera and hold: later duplicates get new ids."""
    _, first = np.unique(lm, return_index=True)
    dup = np.ones(len(lm), bool)
    dup[first] = False
    if dup.any():
        lm = lm.copy()
        lm[dup] = new_ids(int(dup.sum()))
    return lm


__all__ = ["HoldLinker", "HoldObservations"]
