"""Imports stay light: the data layer needs no torch until a Dataset is used, and the models
need no data layer (no OpenCV, no albumentations)."""

import subprocess
import sys


def test_claravid_and_dsp_do_not_import_torch():
    code = (
        "import sys, claravid, claravid.dsp, claravid.sdk, claravid.palettes, claravid.splits\n"
        "from claravid import ClaravidDataset\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
        "from claravid import ClaraVidSegmentation\n"
        "assert 'torch' in sys.modules\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_models_do_not_import_the_data_layer():
    code = (
        "import sys, claravid.models\n"
        "from claravid.models import build_model, export_onnx, OnnxSegmenter\n"
        "heavy = sorted(m for m in ('cv2', 'albumentations', 'claravid.segmentation',\n"
        "               'claravid.transforms', 'claravid.index') if m in sys.modules)\n"
        "assert not heavy, heavy\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
