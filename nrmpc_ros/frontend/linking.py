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

Where the previous hold links few of a camera's tracks (the rig moved far,
or came back near an older view), the tracks still without a partner are
matched against the camera's older holds too: a bounded store keeps every
hold's landmark ids, bearings and descriptors (``tracking.link_store_holds``),
the older holds with the most descriptor matches (a cheap count, no
geometry) are verified with the camera's essential matrix as above
(``tracking.link_older_candidates``), and verified tracks take over those
landmarks (docs/PIPELINE.md, "Landmarks across holds").

A track's own position in a hold is a corner found again in that hold's
anchor frame; it would define the landmark by a different patch in every
hold. So a landmark's position in every hold after its first is where its
reference patch (taken in the first hold that saw it) aligns with the hold's
anchor frame (:mod:`.patch_align`), plus the track's settled offset from the
anchor; a link whose alignment fails starts a new landmark, referenced here
(docs/PIPELINE.md, "Patch alignment"). A link to an older hold is aligned
with the reference patches that hold kept (the latest
``patch_align.older_holds`` of the store keep them, sampled as they enter
it); beyond those a link stays at the corner found in this hold, and says so
(:attr:`HoldObservations.corner`): it enters the estimate with the corner's
viewpoint bias as extra noise (:data:`CORNER_BIAS_PX`).

Aligning is most of a hold's linking, and it needs only the anchor frame: once a hold has settled, the
intake hands its anchor frames over (:meth:`HoldLinker.align_ahead`) and the landmarks its tracks continue
by KLT identity are aligned then, while the hold goes on; its linking takes those alignments where the link
and the anchor position are the ones they were made for (docs/PIPELINE.md, "Aligning ahead").
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, replace

import numpy as np

from ..cameras import pixels_to_bearings
from ..core.rig import Rig
from .holds import Hold
from .patch_align import (
    Alignment,
    PatchAlignConfig,
    ReferencePatches,
    align,
    neighbour_affine,
    reference_patches,
    tangent_frames,
)
from .tracking import Features, TrackingConfig, describe, match_features, verify_correspondences

CORNER_BIAS_PX = 0.3
"""A corner found afresh in each hold marks its landmark up to a bias that depends on the viewpoint (px per axis):
0.18-0.41 px median at 5-15 deg of viewpoint change and about 1 px at 30 deg (docs/RESULTS.md, "Correspondence
error between two holds"); links to older holds on the rendered bags, against the landmark's point ray-cast
from its first hold: 0.18 px median, 0.65 px at the 90th percentile. The std of the extra noise such a link
carries, against the aligned links' few hundredths of a pixel."""


@dataclass
class _CameraHistory:
    """A camera's latest hold: landmark ids, averaged pixels, bearings and descriptors; the landmarks'
    positions in the hold's anchor frame and their reference patches (None without alignment). A reference
    patch is sampled from the anchor image (kept here) only once its landmark is linked in a later hold:
    most tracks are never linked, and sampling their patches would cost as much as the alignment."""

    landmark: np.ndarray
    uv: np.ndarray
    f: np.ndarray
    desc: np.ndarray | None
    valid: np.ndarray
    anchor_uv: np.ndarray | None = None
    ref: ReferencePatches | None = None
    image: np.ndarray | None = None  # the anchor image (float32) the unsampled reference patches come from
    unsampled: np.ndarray | None = None  # (N,) bool: reference patch not sampled yet


@dataclass
class _AlignedAhead:
    """A camera's alignments made before its hold was measured: the anchor image they were made in, the
    landmark and anchor pixel of each, and the alignment (in that order)."""

    image: object
    landmark: np.ndarray
    anchor_uv: np.ndarray
    result: Alignment


@dataclass
class HoldObservations:
    """The observations a hold adds to the sequence: camera, landmark id and bearing of each, and which of them
    link an earlier hold's landmark at a corner found in this hold (a link to an older hold beyond those that
    keep their reference patches, which no alignment reaches: its position carries the corner's viewpoint
    bias, :data:`CORNER_BIAS_PX`)."""

    cam: np.ndarray
    landmark: np.ndarray
    f: np.ndarray
    links: Counter  # per kind: klt, descriptor, rejected (failed the essential-matrix check)
    corner: np.ndarray | None = None  # (N,) bool; None: none


class HoldLinker:
    """Assigns landmark ids to the tracks of successive holds (see the module docstring)."""

    def __init__(self, rig: Rig, cfg: TrackingConfig, align_cfg: PatchAlignConfig | None = None):
        self.rig = rig
        self.cfg = cfg
        self.align_cfg = PatchAlignConfig() if align_cfg is None else align_cfg
        self.reset()

    def reset(self) -> None:
        self._alias = [{} for _ in self.rig.cameras]  # per camera: tracker id -> landmark id
        self._history: list = [None] * self.rig.num_cameras
        # per camera: the holds before the previous one, oldest first (only those with descriptors)
        self._older = [deque(maxlen=max(self.cfg.link_store_holds, 1)) for _ in self.rig.cameras]
        self._ahead: list = [None] * self.rig.num_cameras  # per camera: _AlignedAhead of the hold to link next
        self._next = 0

    def _new_ids(self, n: int) -> np.ndarray:
        out = self._next + np.arange(n, dtype=np.int64)
        self._next += n
        return out

    def link(self, hold: Hold) -> HoldObservations:
        cams, lms, fs, corners = [], [], [], []
        links = Counter()
        for i, ch in enumerate(hold.cameras):
            if ch is None:
                continue
            cam = self.rig.cameras[i]
            alias = self._alias[i]
            lm = self._klt_landmarks(i, ch.ids)
            fresh = lm < 0
            lm[fresh] = self._new_ids(int(fresh.sum()))
            f = pixels_to_bearings(cam, ch.uv)
            img = hold.anchor_images[i] if i < len(hold.anchor_images) else None
            desc, valid = describe(img, ch.anchor_uv, self.cfg) if img is not None else (None, np.zeros(len(lm), bool))
            prev = self._history[i]
            older = np.zeros(len(lm), bool)
            if prev is not None:
                lm = self._link_to(prev, cam, lm, f, ch.uv, desc, valid, links)
                if self.cfg.mode != "klt" and desc is not None and self._older[i]:
                    linked = self._link_older(self._older[i], prev, cam, lm, f, ch.uv, desc, valid, links)
                    older = linked != lm
                    lm = linked
            unique = _unique_per_hold(lm, self._new_ids)
            older &= unique == lm  # a duplicate given a new id links nothing
            lm = unique
            uv, anchor_uv, ref, image, unsampled = ch.uv, ch.anchor_uv, None, None, None
            if img is not None and self.align_cfg.enabled:
                image = np.asarray(img, np.float32)
                ahead = self._ahead[i] if self._ahead[i] is not None and self._ahead[i].image is img else None
                linked = lm
                lm, uv, anchor_uv, ref, unsampled = self._align(prev, cam, image, lm, ch.uv, ch.anchor_uv, links,
                                                                 ahead, self._older[i])
                f = pixels_to_bearings(cam, uv)
                older &= unsampled & (lm == linked)  # older links no kept patch aligned (a failed one links nothing)
            else:
                older[:] = False  # without alignment every link is a corner: the nominal noise covers them alike
            alias.update(zip(ch.ids.tolist(), lm.tolist()))
            if prev is not None and prev.desc is not None and self.cfg.link_store_holds > 0:
                self._store(i, cam, prev)
            self._history[i] = _CameraHistory(lm, uv, f, desc, valid, anchor_uv, ref, image, unsampled)
            self._ahead[i] = None
            cams.append(np.full(len(lm), i, np.int64))
            lms.append(lm)
            fs.append(f)
            corners.append(older)
        if not cams:
            return HoldObservations(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), links)
        corner = np.concatenate(corners)
        links["corner"] += int(np.count_nonzero(corner))
        return HoldObservations(np.concatenate(cams), np.concatenate(lms), np.concatenate(fs), links,
                                corner if corner.any() else None)

    def _klt_landmarks(self, i: int, ids) -> np.ndarray:
        """Camera i's landmark of each tracker id by KLT identity (-1: none, or descriptors only)."""
        if self.cfg.mode == "descriptors":
            return np.full(len(ids), -1, np.int64)
        alias = self._alias[i]
        return np.array([alias.get(int(k), -1) for k in ids], dtype=np.int64)

    def align_ahead(self, anchors: list, images: list) -> int:
        """Align, in each camera's anchor frame of a hold not measured yet, the reference patches of the
        landmarks its tracks continue by KLT identity from the previous hold (``anchors``: per camera (tracker
        ids, pixels) of the anchor frame or None; ``images``: the anchor frames). :meth:`link` of that hold
        takes them for the links it keeps at those anchor pixels, and aligns the others itself. Returns the
        number of patches aligned."""
        done = 0
        for i, (anchor, img) in enumerate(zip(anchors, images)):
            self._ahead[i] = None
            prev = self._history[i]
            if anchor is None or img is None or prev is None or prev.ref is None or not self.align_cfg.enabled:
                continue
            ids, uv = anchor
            lm = self._klt_landmarks(i, ids)
            _, ip, ic = np.intersect1d(prev.landmark, lm, return_indices=True)
            if not len(ic):
                continue
            cam = self.rig.cameras[i]
            res = self._aligned(prev, cam, np.asarray(img, np.float32), ip, uv[ic], np.ones(len(ip), bool))
            self._ahead[i] = _AlignedAhead(img, lm[ic], np.asarray(uv[ic], np.float64), res)
            done += len(ic)
        return done

    def _store(self, i: int, cam, prev: _CameraHistory) -> None:
        """Camera ``i``'s previous hold into the store of older holds: its descriptors for matching, and while it
        is among the latest ``patch_align.older_holds`` its reference patches too (those not sampled yet sampled
        now from its anchor image, which is not kept), so that a link to it can be aligned."""
        keep = self.align_cfg.older_holds
        ref = None
        if keep > 0 and prev.ref is not None and prev.image is not None:
            todo = np.flatnonzero(prev.unsampled)
            if len(todo):
                new = reference_patches(cam, prev.image, prev.anchor_uv[todo], self.align_cfg)
                prev.ref.values[todo] = new.values
                prev.ref.valid[todo] = new.valid
            ref = prev.ref
        store = self._older[i]
        store.append(replace(prev, ref=ref, image=None, unsampled=np.zeros(len(prev.landmark), bool)))
        if len(store) > keep:
            store[-keep - 1].ref = None  # beyond the kept patches: descriptors only

    def _aligned(self, prev: _CameraHistory, cam, image, ip, uv0, which) -> Alignment:
        """Alignment in ``image`` (float32) of the reference patches of the previous hold's landmarks ``ip`` that
        ``which`` selects, near anchor pixels uv0 (len(ip), 2); the starting warps come from all of them."""
        acfg = self.align_cfg
        todo = ip[which][prev.unsampled[ip[which]]]
        if len(todo):  # reference patches of landmarks first linked now, from their first hold's image
            new = reference_patches(cam, prev.image, prev.anchor_uv[todo], acfg)
            prev.ref.values[todo] = new.values
            prev.ref.valid[todo] = new.valid
            prev.unsampled[todo] = False
        tf_prev, tf_cur = tangent_frames(cam, prev.anchor_uv[ip]), tangent_frames(cam, uv0)
        start = neighbour_affine(tf_prev.f, tf_cur.f, tf_prev, tf_cur, acfg.neighbours) @ prev.ref.affine[ip]
        return align(cam, image, prev.ref.take(ip[which]), uv0[which], start[which], acfg)

    def _align(self, prev: _CameraHistory | None, cam, image, lm, uv, anchor_uv, links: Counter,
               ahead: _AlignedAhead | None = None, older=()) -> tuple:
        """(landmark ids, positions, anchor-frame positions, reference patches, which of those are still to be
        sampled from ``image``) of a camera's hold once every linked landmark's reference patch is aligned with
        the anchor frame ``image`` (float32); a failed alignment breaks the link (new landmark). Landmarks first
        seen here take their reference patch from here (sampled when a later hold links them). The previous
        hold's landmarks are aligned from its patches, the others linked to an older hold from the patches of
        the newest hold of ``older`` (the store, oldest first) that kept them."""
        acfg = self.align_cfg
        uv, anchor_uv, lm = uv.copy(), anchor_uv.copy(), lm.copy()
        n = len(lm)
        ref = ReferencePatches(np.zeros((n, (2 * acfg.half_size_px + 1) ** 2), np.float32),
                               np.zeros((n, (2 * acfg.half_size_px + 1) ** 2), bool),
                               np.broadcast_to(np.eye(2), (n, 2, 2)).copy())
        fresh = np.ones(n, bool)  # the landmarks that take their reference patch from this hold
        sources = ([prev] if prev is not None else []) + [h for h in reversed(older) if h.ref is not None]
        for k, src in enumerate(sources):
            if src.ref is None:
                continue
            mine = np.flatnonzero(fresh)
            _, ip, ic = np.intersect1d(src.landmark, lm[mine], assume_unique=True, return_indices=True)
            if not len(ic):
                continue
            ic = mine[ic]
            res = self._with_ahead(src, cam, image, ip, lm[ic], anchor_uv[ic], ahead if k == 0 else None)
            good, bad = ic[res.ok], ic[~res.ok]
            settled = uv[good] - anchor_uv[good]  # the track's settled offset from the anchor frame
            anchor_uv[good] = res.uv[res.ok]
            uv[good] = anchor_uv[good] + settled
            ref.values[good] = src.ref.values[ip[res.ok]]
            ref.valid[good] = src.ref.valid[ip[res.ok]]
            ref.affine[good] = res.affine[res.ok]
            fresh[good] = False
            lm[bad] = self._new_ids(len(bad))  # a failed alignment starts a landmark referenced here
            links["aligned"] += len(good)
            links["alignment failed"] += len(bad)
        return lm, uv, anchor_uv, ref, fresh

    def _with_ahead(self, prev: _CameraHistory, cam, image, ip, lm, uv0, ahead: _AlignedAhead | None) -> Alignment:
        """Alignments of the links (previous hold's landmarks ``ip``, now ``lm`` at anchor pixels uv0): those made
        ahead for the same landmark at the same anchor pixel taken, the others made here."""
        n = len(ip)
        found = np.full(n, -1)
        if ahead is not None and len(ahead.landmark):
            order = np.argsort(ahead.landmark)
            pos = np.clip(np.searchsorted(ahead.landmark, lm, sorter=order), 0, len(order) - 1)
            k = order[pos]
            same = (ahead.landmark[k] == lm) & np.all(ahead.anchor_uv[k] == uv0, axis=1)
            found[same] = k[same]
        miss = found < 0
        if not miss.any():
            r = ahead.result
            return Alignment(r.uv[found], r.affine[found], r.ok[found], r.correlation[found], 0, r.std_px[found])
        res = self._aligned(prev, cam, image, ip, uv0, miss)
        if not (~miss).any():
            return res
        r, k = ahead.result, found[~miss]
        uv, affine = np.empty((n, 2)), np.empty((n, 2, 2))
        ok, corr, std = np.empty(n, bool), np.empty(n), np.empty(n)
        for out, mine, theirs in ((uv, res.uv, r.uv), (affine, res.affine, r.affine), (ok, res.ok, r.ok),
                                  (corr, res.correlation, r.correlation), (std, res.std_px, r.std_px)):
            out[miss], out[~miss] = mine, theirs[k]
        return Alignment(uv, affine, ok, corr, res.iterations, std)

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

    def _link_older(self, older, prev: _CameraHistory, cam, lm, f, uv, desc, valid, links: Counter) -> np.ndarray:
        """Landmark ids after linking the tracks the previous hold left without a partner to the camera's older
        holds (see the module docstring); unchanged while the previous hold links enough of them."""
        cfg = self.cfg
        linked = np.isin(lm, prev.landmark)
        if np.count_nonzero(linked) >= cfg.min_klt_links:
            return lm
        free = np.flatnonzero(valid & ~linked)
        if len(free) < cfg.min_matches_per_camera:
            return lm
        mine = Features(uv[free], desc[free])
        counts = []
        for old in older:  # cheap: descriptor matches only, per stored hold
            pv = np.flatnonzero(old.valid & ~np.isin(old.landmark, lm))
            n = len(match_features(Features(old.uv[pv], old.desc[pv]), mine, cfg)[0]) if len(pv) >= 2 else 0
            counts.append(n)
        order = np.argsort(-np.asarray(counts), kind="stable")[: cfg.link_older_candidates]
        out = lm.copy()
        for h in order:
            if counts[h] < cfg.min_matches_per_camera or len(free) < cfg.min_matches_per_camera:
                break
            old = older[int(h)]
            pv = np.flatnonzero(old.valid & ~np.isin(old.landmark, out))
            ia, ib = match_features(Features(old.uv[pv], old.desc[pv]), Features(uv[free], desc[free]), cfg)
            if len(ia) < cfg.min_matches_per_camera:
                continue
            ok = verify_correspondences(cam, old.f[pv[ia]], f[free[ib]], cfg)
            out[free[ib[ok]]] = old.landmark[pv[ia[ok]]]
            links["older"] += int(np.count_nonzero(ok))
            links["rejected"] += int(np.count_nonzero(~ok))
            free = np.setdiff1d(free, free[ib[ok]])
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


__all__ = ["CORNER_BIAS_PX", "HoldLinker", "HoldObservations"]
