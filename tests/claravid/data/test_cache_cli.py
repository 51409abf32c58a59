"""claravid-cache on hostile label files: listed as unusable (exit 1), never a traceback."""

import re

import pytest

from claravid.data.cache_cli import main
from tests.claravid.io.test_modalities import png_claiming


@pytest.mark.parametrize("workers", ["0", "2"])
def test_a_label_png_claiming_more_than_2_30_pixels_is_listed(
    writable_root, tmp_path, capsys, workers
):
    # OpenCV's cv2.error ended the run in a traceback (in the workers and without them).
    pan = sorted(writable_root.glob("003_urban_1/panoptic_seg/45deg_low_h/*.png"))[1]
    pan.write_bytes(png_claiming(40000, 30000))
    argv = [str(writable_root), "--missions", "urban_1", "--altitude", "low", "--cache-dir",
            str(tmp_path / "cache"), "--no-progress", "--workers", workers]  # fmt: skip
    assert main(argv) == 1
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert "Traceback" not in text and "cv2.error" not in text
    lines = [line for line in text.splitlines() if str(pan) in line]
    assert len(lines) == 1, text
    assert re.search(
        r"its header claims 40000×30000 = 1,200,000,000 pixels, more than the 1,073,741,824 "
        r"\(2\^30\) the readers decode",
        lines[0],
    ), lines[0]
    assert "built 5 entries" in text, text
