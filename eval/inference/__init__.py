"""Inference (torch): what an evaluation reads and how each image gets its confusion.

``data`` (the images and labels of ClaraVid, UAVid or a folder), ``sources`` (a checkpoint or
an ONNX file, and how it is run), ``windows`` (sliding windows), ``confusion`` (an image's and
its tiles' confusions), ``run_model`` (a model over a dataset), ``label_maps`` (saved label
maps on disk), ``metric_csv`` (per-image metrics from a CSV), ``complexity_job`` (delentropy
computed beside inference), ``collect`` (one evaluation's per-image table, sharded under
torchrun) and ``hardest`` (the hardest images kept for the report).
"""
