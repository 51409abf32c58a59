"""One evaluation's per-image table: images -> per-image confusions, complexity and the
measures beyond mIoU.

:func:`collect` produces the per-image table (:class:`~claravid.eval.analysis.table.EvalResult`)
from a model or from saved label maps, on one process or sharded over ``torchrun`` ranks (each rank
evaluates every ``world_size``-th image and measures its complexity meanwhile; rank 0 gathers
everything in dataset order, so the table is the same as one process's). With cross-view pairs
each rank takes a contiguous run of images instead, so consecutive frames of a pass meet on one
rank; a pair whose next frame another rank evaluates is still measured by its own frame's rank
(:mod:`claravid.eval.inference.pair_stream`): counted once. The report folder is then
:func:`claravid.eval.report.folder.write_outputs`; the command line
(:mod:`claravid.eval.cli.evaluate`)
is a thin layer over both.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from claravid.data.palette_fold import PaletteFold
from claravid.dsp.tiles import check_tile_count, check_tile_size
from claravid.eval.analysis.metrics import mean_iou
from claravid.eval.analysis.quality_table import (
    CONSISTENCY,
)
from claravid.eval.analysis.table import EvalResult
from claravid.eval.analysis.tile_bins import TileTable
from claravid.eval.inference.background import Background
from claravid.eval.inference.complexity_job import ComplexityJob
from claravid.eval.inference.hardest import Hardest
from claravid.eval.inference.image_sums import predict_with_confidence
from claravid.eval.inference.pair_stream import PairKeeper, PairStream
from claravid.eval.inference.quality_collect import label_map_measure, pair_item, quality_table
from claravid.eval.inference.quality_plan import QualityPlan, plan_quality
from claravid.eval.inference.run_model import ImageScore, evaluate_model
from claravid.eval.inference.sources import ModelSource
from claravid.eval.inference.windows import WindowConfig
from claravid.eval.inputs.datasets import EvalData
from claravid.eval.inputs.label_maps import (
    check_missing,
    label_map_confusions,
    write_marker,
)
from claravid.eval.inputs.label_maps import write_prediction as save_label_map
from claravid.eval.inputs.pass_frames import (
    PairResult,
    PassFrames,
    pairs_unavailable,
)
from claravid.infra import distributed
from claravid.infra.cli import USER_ERRORS, UsageError
from claravid.io.jpeg_region import image_size


@dataclass
class Collected:
    """What :func:`collect` returns: the table, the skipped images, kept hardest predictions
    and the pairs of lowest consistency (thumbnails, :class:`PairKeeper` items), lowest first."""

    result: EvalResult
    skipped: list[str]
    hardest: dict[int, np.ndarray]
    pairs: list[dict[str, Any]] = field(default_factory=list)


def _from_worker(exc: Exception) -> Exception:
    """A DataLoader worker's data error (an unreadable image) as the one-line error it was.

    The DataLoader re-raises it with the worker's traceback in the message (or, when the
    exception cannot be rebuilt from one string, as a RuntimeError); its last line is
    ``module.ErrorType: message``.
    """
    text = str(exc)
    if "DataLoader worker" not in text.split("\n", 1)[0]:
        return exc
    last = text.rstrip().splitlines()[-1]
    name, _, message = last.partition(": ")
    if name.rsplit(".", 1)[-1].endswith(("Error", "Exception")) and message:
        return ValueError(message)
    return exc


def _raise_any(error: BaseException | None) -> None:
    """Raise on every rank when any rank failed (the others would wait forever otherwise)."""
    me = distributed.current().rank
    summary = None if error is None else (isinstance(error, USER_ERRORS), str(error))
    failures = distributed.gather_in_order([summary], [me])
    if error is not None:
        raise error
    for failure in failures:
        if failure is not None:
            user, message = failure
            raise (UsageError if user else RuntimeError)(f"another rank failed: {message}")


@dataclass(frozen=True)
class CollectSettings:
    """How :func:`collect` works through the images.

    Attributes:
        window: sliding windows (model only; default :class:`WindowConfig`'s).
        measures: complexity measures, ``delent`` first.
        tile_size: also each tile's delentropy and confusion (see
            :mod:`claravid.eval.analysis.tile_bins`).
        hardest: how many of the hardest images' predictions to keep for overlays.
        workers: processes for complexity and for decoding images (0: threads only).
        device: where the model runs.
        save_predictions: also write the model's label maps here.
        allow_missing: skip images without a prediction instead of failing.
        progress: show a progress bar.
        quality: the measures beyond mIoU
            (:func:`~claravid.eval.inference.quality_plan.plan_quality`); None: each one on
            where the source and data allow it.
        fold: a fine model (or its label maps) scored through the data's palette
            (:mod:`claravid.data.palette_fold`); None: the model predicts the palette's classes.
    """

    window: WindowConfig | None = None
    measures: Sequence[str] = ("delent",)
    tile_size: int | None = None
    hardest: int = 4
    workers: int = 0
    device: torch.device | str = "cpu"
    save_predictions: str | Path | None = None
    allow_missing: bool = False
    progress: bool = False
    quality: QualityPlan | None = None
    fold: PaletteFold | None = None


def contiguous_shard(n: int) -> list[int]:
    """This rank's contiguous run of ``range(n)`` (ranks in order, sizes within one)."""
    info = distributed.current()
    return list(range(info.rank * n // info.world_size, (info.rank + 1) * n // info.world_size))


def collect(
    data: EvalData,
    *,
    model: ModelSource | None = None,
    predictions: str | Path | None = None,
    settings: CollectSettings | None = None,
    source: dict[str, Any] | None = None,
) -> Collected:
    """Per-image confusions and complexities of ``data`` from a model or saved predictions.

    Under ``torchrun`` (an initialised process group) each rank takes its shard; every rank
    returns the full, gathered table.

    Args:
        data: the images (:func:`claravid.eval.inputs.datasets.open_data`).
        model: a loaded model (exclusive with ``predictions``).
        predictions: the folder of saved label maps.
        settings: windows, measures, tiles, workers, device... (default
            :class:`CollectSettings`).
        source: the report's ``source`` entries.
    """
    s = settings or CollectSettings()
    if (model is None) == (predictions is None):
        raise ValueError("give exactly one of a model and a predictions folder")
    plan = s.quality or plan_quality({}, has_scores=model is not None,
                                     pairs_reason=pairs_unavailable(data))  # fmt: skip
    skipped: list[int] = []
    present = list(range(len(data)))
    if predictions is not None:
        present, skipped = check_missing(predictions, data, s.allow_missing)
    # Pairs: consecutive frames on one rank (a rank's last frame predicts its next one).
    shard = contiguous_shard if plan.on(CONSISTENCY) else distributed.shard_indices
    mine = [present[i] for i in shard(len(present))]
    frames = PassFrames(data) if plan.on(CONSISTENCY) else None
    work = _Work(
        data, mine, s, plan, frames,
        keeper=Hardest(s.hardest if model is not None and s.save_predictions is None else 0),
        pair_keeper=PairKeeper(s.hardest if frames is not None else 0),
    )  # fmt: skip
    if s.tile_size is not None and mine:  # before any work: a grid too fine for the first image
        check_tile_size(s.tile_size)
        width, height = image_size(data.paths[mine[0]])
        check_tile_count((height, width), s.tile_size, str(data.paths[mine[0]]))
    if s.save_predictions is not None and distributed.current().is_main:
        # The marker first: an interrupted run's partial label maps are still this tool's, so
        # the same command can be run again without --overwrite.
        write_marker(s.save_predictions, data.palette, source or {}, complete=False)
    scored = _measure(work, model, predictions)
    return _gather(work, scored, present, skipped, source)


@dataclass
class _Work:
    """One rank's share of a collection and what keeps its hardest images and pairs."""

    data: EvalData
    mine: list[int]
    settings: CollectSettings
    plan: QualityPlan
    frames: PassFrames | None
    keeper: Hardest
    pair_keeper: PairKeeper


@dataclass
class _Scored:
    """What one rank measured of its images, in its order: confusions, tiles' confusions, the
    (boundary, calibration) sums, the pairs by key, and the complexities and tiles' values."""

    confusions: list[np.ndarray] = field(default_factory=list)
    tile_confs: list[np.ndarray | None] = field(default_factory=list)
    extras: list[tuple[Any, Any]] = field(default_factory=list)
    pairs: dict[str, PairResult] = field(default_factory=dict)
    values: dict[str, list[float]] = field(default_factory=dict)
    tile_values: list[np.ndarray | None] = field(default_factory=list)


def _measure(work: _Work, model: ModelSource | None, predictions: str | Path | None) -> _Scored:
    """Score this rank's images while their complexity is measured; raise on every rank when
    any rank failed."""
    s, data = work.settings, work.data
    scored = _Scored()
    error: BaseException | None = None
    job: ComplexityJob | None = None
    try:
        # Complexity starts first and runs while the model (or the PNG reader) works: in
        # worker processes beside a model (a long run), in threads beside the PNG reader.
        job = ComplexityJob(
            [data.paths[i] for i in work.mine],
            s.measures,
            workers=s.workers if model is not None else 0,
            threads=max(1, s.workers),
            tile_size=s.tile_size,
        )
        if model is not None:
            scored = _score_model(work, model)
        else:
            assert predictions is not None  # one of model and predictions, checked by collect
            scored = _score_label_maps(work, predictions)
        scored.values = job.result()
        scored.tile_values = job.tiles()
        if s.tile_size is not None:
            _check_tile_grids(data, work.mine, scored.tile_values, scored.tile_confs)
    except BaseException as exc:
        if job is not None:
            job.stop()  # join the threads before the error ends the process
        if not isinstance(exc, Exception):  # Ctrl-C: no rank exchange, just stop
            raise
        error = _from_worker(exc)
    _raise_any(error)
    return scored


def _score_model(work: _Work, model: ModelSource) -> _Scored:
    """Run the model over this rank's images: confusions, the measures beyond mIoU, the saved
    label maps and the pairs (each image's measures and pair in threads beside the next
    prediction)."""
    s, data, frames = work.settings, work.data, work.frames
    k = data.palette.num_classes
    with Background(max(1, s.workers)) as background:
        stream = None
        if frames is not None:
            window = (s.window or WindowConfig()).for_model(model.model)

            def predict_other(key: str) -> np.ndarray:
                image = frames.image(key).to(s.device)
                ids, _ = predict_with_confidence(model.model, image, window, False, s.fold)
                return ids.to("cpu", torch.uint8).numpy()

            stream = PairStream(frames, [data.keys[i] for i in work.mine], k, predict_other,
                                work.pair_keeper, work.mine, background)  # fmt: skip

        def on_score(sample: dict[str, Any], pred: torch.Tensor, score: ImageScore) -> None:
            work.keeper.offer(int(sample["index"]), mean_iou(score.confusion), pred)
            if s.save_predictions is None and stream is None:
                return
            ids = pred.to("cpu", torch.uint8).numpy()
            if s.save_predictions is not None:
                save_label_map(s.save_predictions, score.key, ids)
            if stream is not None:
                stream.add(score.key, ids, np.asarray(sample["mask"], dtype=np.uint8))

        scores = evaluate_model(
            model.model,
            data.dataset,
            k,
            s.window,
            device=s.device,
            indices=work.mine,
            num_workers=s.workers,
            tile_size=s.tile_size,
            progress=s.progress,
            on_score=on_score,
            measures=work.plan.image_measures(),
            background=background,
            fold=s.fold,
        )
        return _Scored(
            confusions=[score.confusion for score in scores],
            tile_confs=[score.tiles for score in scores],
            extras=[(score.boundary, score.calibration) for score in scores],
            pairs={} if stream is None else stream.finish(),
        )


def _score_label_maps(work: _Work, predictions: str | Path) -> _Scored:
    """Read this rank's saved label maps: confusions, boundary sums and pairs."""
    s, data, mine = work.settings, work.data, work.mine
    measure = label_map_measure(data, predictions, work.plan, work.frames, work.pair_keeper,
                                s.fold)  # fmt: skip
    scored = label_map_confusions(data, predictions, mine, threads=max(1, s.workers),
                                  tile_size=s.tile_size, progress=s.progress,
                                  measure=measure, fold=s.fold)  # fmt: skip
    pairs = {data.keys[i]: e[1] for i, (_, _, e) in zip(mine, scored, strict=True)
             if e is not None and e[1] is not None}  # fmt: skip
    return _Scored(
        confusions=[c for c, _, _ in scored],
        tile_confs=[t for _, t, _ in scored],
        extras=[(None if e is None else e[0], None) for _, _, e in scored],
        pairs=pairs,
    )


def _gather(
    work: _Work,
    scored: _Scored,
    present: list[int],
    skipped: list[int],
    source: dict[str, Any] | None,
) -> Collected:
    """Every rank's rows, hardest images and pairs, in dataset order: the table."""
    s, data, mine = work.settings, work.data, work.mine
    k, tile_size, hardest = data.palette.num_classes, s.tile_size, s.hardest
    rows = [
        (scored.confusions[j], {m: scored.values[m][j] for m in scored.values},
         (scored.tile_values[j], scored.tile_confs[j]) if tile_size is not None else None,
         scored.extras[j], scored.pairs.get(data.keys[mine[j]]))
        for j in range(len(mine))
    ]  # fmt: skip
    rows = distributed.gather_in_order(rows, mine)
    rank = distributed.current().rank
    kept = distributed.gather_in_order([work.keeper.heap], [rank])
    kept_pairs = distributed.gather_in_order([work.pair_keeper.heap], [rank])
    order = sorted(present)
    # Entries are (-mIoU, -index, prediction): the hardest are the largest.
    entries = [e for part in kept for e in part]
    heap = heapq.nlargest(max(0, hardest), entries, key=lambda e: e[:2])
    result = EvalResult(
        paths=[data.paths[i] for i in order],
        keys=[data.keys[i] for i in order],
        confusions=np.stack([r[0] for r in rows]).astype(np.int64),
        complexity={m: np.asarray([r[1][m] for r in rows], dtype=np.float64) for m in s.measures},
        attributes={a: [v[i] for i in order] for a, v in data.attributes.items()},
        classes=list(data.palette.names),
        palette=data.palette.name,
        source={**(source or {}), "skipped": [data.paths[i] for i in skipped]},
        tiles=None
        if tile_size is None
        else TileTable.from_images(tile_size, [_tiles(r[2]) for r in rows], k),
        quality=quality_table(work.plan, rows, k),
    )
    # Table rows are positions in `present`; hardest predictions are keyed by those too.
    position = {index: pos for pos, index in enumerate(order)}
    worst = heapq.nlargest(max(0, hardest), [e for part in kept_pairs for e in part],
                           key=lambda e: e[:2])  # fmt: skip
    sheet = []
    if work.frames is not None and distributed.current().is_main:
        sheet = [pair_item(work.frames, item) for _, _, item in worst]
    return Collected(
        result,
        [data.paths[i] for i in skipped],
        {position[-i]: p for _, i, p in heap},
        sheet,
    )


def _check_tile_grids(
    data: EvalData,
    indices: Sequence[int],
    values: Sequence[np.ndarray | None],
    confusions: Sequence[np.ndarray | None],
) -> None:
    """The image's tile grid (its delentropy) must be the labels' grid (their confusions)."""
    for index, value, conf in zip(indices, values, confusions, strict=True):
        if value is None or conf is None or value.shape != conf.shape[:2]:
            got = None if value is None else value.shape
            want = None if conf is None else conf.shape[:2]
            raise ValueError(
                f"{data.paths[index]}: the image gives a {got} tile grid and its labels a {want} "
                "one: --tiles needs labels at the image's resolution"
            )


def _tiles(
    counted: tuple[np.ndarray | None, np.ndarray | None] | None,
) -> tuple[np.ndarray, np.ndarray]:
    """An image's (delentropy, confusions) per tile: counted for every image with a tile size."""
    assert counted is not None and counted[0] is not None and counted[1] is not None
    return counted[0], counted[1]
