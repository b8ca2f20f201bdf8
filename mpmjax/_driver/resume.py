"""Checkpoint and resume: reading the checkpoint a resumed run continues from and checking that it
is the same scene (``read_for_resume``, ``check_same_scene``), restoring the state and the
series (``restore``), and writing checkpoints during the run (``Checkpointer``)."""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import h5py
import jax
import jax.numpy as jnp
import numpy as np

from .. import _hazard
from .._io import _jsonable, read_checkpoint
from .._io import write_checkpoint as _write_ckpt
from .._schema import SceneError
from .._version import __version__

CHECKPOINT_EVERY = 10  # frames between checkpoints (default of --checkpoint-every)
CHECKPOINT_NAME = "checkpoint.h5"  # in the output folder, while a run is not complete


def resume_command(out: Path) -> str:
    return f"mpmjax run --resume {shlex.quote(str(out))}"


def _result_complete(path: Path) -> bool:
    try:
        with h5py.File(path, "r") as f:
            return bool(f.attrs.get("complete", False))
    except OSError:
        return False


def read_for_resume(out: Path, lock) -> tuple:
    """The checkpoint in ``out`` as ``(state, frame, config hash, meta)``; ``SceneError`` where
    there is none (or the run there is complete) or it cannot be read.  Takes the folder's
    ``lock`` first, so that no other run changes the checkpoint meanwhile."""
    ckpt_path = out / CHECKPOINT_NAME
    if out.is_dir():
        lock.acquire()  # before the checkpoint is read: no other run may change it meanwhile
    if not ckpt_path.is_file():
        done = (out / "result.h5").is_file() and _result_complete(out / "result.h5")
        raise SceneError(
            f"--resume {out}: "
            + ("the run there is already complete; nothing to resume" if done else f"no {ckpt_path.name} there")
        )
    try:
        ckpt = read_checkpoint(ckpt_path)
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise SceneError(f"--resume {out}: {ckpt_path} cannot be read: {type(e).__name__}: {e}") from None
    _check_meta(ckpt_path, ckpt)
    return ckpt


# what a checkpoint's metadata must hold (``Checkpointer.meta_base`` and ``acc``), with its type
_META = {"scene_source": str, "overrides": list, "cfg": dict, "acc": dict}
_ACC = ("times", "fronts", "farthest", "kinetic", "lost_reported", "n_outflow", "wall_s", "mass0")


def _damaged(path, what) -> SceneError:
    return SceneError(
        f"--resume: the checkpoint {path} is damaged: {what}; allowed: a checkpoint written by mpmjax run (rerun "
        "without --resume to start again)"
    )


def _check_meta(path: Path, ckpt: tuple) -> None:
    """``SceneError`` naming the checkpoint and the damage where its frame or metadata are not what a
    run writes (a frame < 0, a missing or mistyped entry)."""
    _, frame, _, meta = ckpt
    if frame < 0:
        raise _damaged(path, f"frame = {frame} (allowed: >= 0)")
    if not isinstance(meta, dict):
        raise _damaged(path, f"its metadata is a {type(meta).__name__}, not a table")
    for k, t in _META.items():
        if not isinstance(meta.get(k), t):
            raise _damaged(path, f"metadata entry {k!r} is {'missing' if k not in meta else type(meta[k]).__name__}")
    missing = [k for k in _ACC if k not in meta["acc"] and k != "farthest"]  # "farthest": restore() explains
    if missing:
        raise _damaged(path, f"the series entries {', '.join(missing)} are missing from its metadata")
    times = meta["acc"]["times"]
    if not isinstance(times, list) or len(times) != frame + 1:
        held = f"{len(times)} frames" if isinstance(times, list) else f"a {type(times).__name__}"
        raise _damaged(path, f"frame = {frame}, but its series hold {held}, not frames 0 .. {frame}")


def check_checkpoint(out: Path, ckpt: tuple, setup) -> None:
    """``SceneError`` naming the checkpoint unless its frame is within the scene's run and its state
    arrays have the shapes and dtypes of the built scene's (checked before the state is used)."""
    path = out / CHECKPOINT_NAME
    state, frame = ckpt[0], ckpt[1]
    n_frames = setup.scene.n_frames
    if frame > n_frames:
        raise _damaged(path, f"frame = {frame} is past the run's last frame {n_frames}")
    for name, want in setup.state._asdict().items():
        got = getattr(state, name, None)
        if want is None or isinstance(want, dict):
            continue
        want_shape, want_dtype = np.shape(want), np.asarray(want).dtype
        if got is None or np.shape(got) != want_shape or np.asarray(got).dtype != want_dtype:
            what = "missing" if got is None else f"{np.asarray(got).dtype}{list(np.shape(got))}"
            raise _damaged(
                path, f"state array {name} is {what}; the scene's is {want_dtype}{list(want_shape)}"
            )


def check_same_scene(out: Path, ckpt: tuple, cfg: dict, chash: str, source: str, overrides: list) -> None:
    """``SceneError`` naming the differing keys unless the checkpoint was written for ``cfg``."""
    if ckpt[2] == chash:
        return
    old = ckpt[3].get("cfg", {})
    diff = [k for k in sorted(set(old) | set(cfg)) if json.dumps(old.get(k)) != json.dumps(_jsonable(cfg.get(k)))]
    shown = ", ".join(f"{k}: {old.get(k)!r} in the checkpoint, {_jsonable(cfg.get(k))!r} now" for k in diff[:6])
    added = sorted(set(cfg) - set(old))
    if not shown and added:  # the same values, but keys this version of mpmjax has and the checkpoint's had not
        shown = f"none in value, but the scene keys {', '.join(added[:6])} are newer than the checkpoint"
    raise SceneError(
        f"--resume {out}: the checkpoint was written for a different scene or different --set overrides "
        f"(checkpoint: {ckpt[3]['scene_source']} {ckpt[3]['overrides']}; now: {source} {overrides}); "
        f"differing keys: {shown or 'none found (the scene file changed)'}. Resume with the original scene "
        f"and overrides (or none: `{resume_command(out)}`)"
    )


def restore(ckpt: tuple, out: Path, advance, n_frames: int, log) -> tuple:
    """``(state, frame, series)`` of a resumed run from its checkpoint (the hazard maps restored
    into ``advance``)."""
    st_np, done, _, meta = ckpt
    state = jax.tree_util.tree_map(jnp.asarray, st_np)
    acc = meta["acc"]
    if "farthest" not in acc:
        raise SceneError(
            f"--resume {out}: the checkpoint was written by mpmjax {meta.get('code_version', '?')}, before "
            "the free-surface runout (docs/output.md 'Runout'); its runout series cannot be continued: rerun "
            "without --resume"
        )
    if isinstance(advance, _hazard.HazardAdvance):
        advance.restore(acc["hazard"])
    log(f"resuming {out} from the checkpoint at frame {done}/{n_frames} (t = {float(state.t):.4g} s)")
    return state, done, acc


class Checkpointer:
    """Writes the run's checkpoint (the state, the frame, the series ``acc`` and, with hazard maps,
    the maps so far); ``last`` is the frame of the latest one on disk (-1: none)."""

    def __init__(self, path: Path, chash: str, source: str, overrides: list, cfg: dict, last: int):
        self.path, self.chash, self.last = path, chash, last
        self.meta_base = dict(scene_source=source, overrides=overrides, cfg=_jsonable(cfg), code_version=__version__)

    def write(self, state, frame: int, acc: dict, advance) -> None:
        if isinstance(advance, _hazard.HazardAdvance):
            acc["hazard"] = advance.to_json()
        _write_ckpt(self.path, state, frame, self.chash, dict(self.meta_base, acc=acc))
        self.last = frame
