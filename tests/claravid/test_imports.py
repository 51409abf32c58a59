"""Importing the data and complexity layers stays light: no torch until a Dataset is used."""

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
