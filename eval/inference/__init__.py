"""Inference (torch): what an evaluation reads and how each image gets its sums.

``data`` (the images and labels of ClaraVid, UAVid or a folder), ``sources`` (a checkpoint or
an ONNX file, and how it is run), ``windows`` (sliding windows), ``confusion`` (an image's and
its tiles' confusions), ``boundary``, ``calibration`` and ``image_measures`` (an image's
Boundary IoU and calibration sums), ``cross_view``, ``pairs``, ``pass_frames``, ``pair_stream``
and ``pair_marks`` (each frame's pair with the next frame of its pass: the sums, the frames and
their geometry, who measures a pair, the sheet's marks), ``quality_plan`` (which measures a run
takes), ``background`` (their threads beside the model), ``run_model`` (a model over a
dataset), ``label_maps`` (saved label maps on disk), ``metric_csv`` (per-image metrics from a
CSV), ``complexity_job`` (delentropy computed beside inference), ``collect`` and
``quality_collect`` (one evaluation's per-image table, sharded under torchrun) and ``hardest``
(the hardest images kept for the report).
"""
