"""Inference (torch): sources, sliding windows, running the model, and collecting one evaluation's
per-image table.

``sources`` (a checkpoint or an ONNX file, and how it is run), ``windows`` (sliding windows),
``augment`` (test-time augmentation: the published protocols' scales and mirror),
``run_model`` (a model over a dataset), ``background`` (the measures' threads beside the model),
``quality_plan`` (which measures a run takes), ``pair_stream`` (pairs measured as the run goes),
``complexity_job`` (delentropy computed beside inference), ``collect`` and ``quality_collect``
(one evaluation's per-image table, sharded under torchrun) and ``hardest`` (the hardest images
kept for the report). What they read is :mod:`claravid.eval.inputs`; the sums they take,
:mod:`claravid.eval.measures`.
"""
