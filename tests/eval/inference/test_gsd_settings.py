"""--gsd: the data's metres per pixel matched to the model's recorded GSD."""

import pytest

from claravid import models
from claravid.eval.inference.sources import load_source, resolve_settings
from claravid.infra.cli import UsageError


@pytest.fixture(scope="module")
def with_gsd(model_files, tmp_path_factory):
    path = tmp_path_factory.mktemp("gsd") / "gsd.pt"
    record = {"metres_per_pixel": 0.04, "source": "data.gsd"}
    return models.save_checkpoint(model_files["model"], path, gsd=record)


def test_the_scale_brings_the_data_to_the_models_gsd(with_gsd):
    source = load_source(with_gsd)
    assert source.defaults["gsd"] == 0.04
    settings = resolve_settings(source, window=28, gsd=0.02)  # data twice as fine: halve it
    assert settings.window.scale == pytest.approx(0.5)
    described = settings.describe()
    assert described["gsd"] == {"model": 0.04, "data": 0.02}
    assert described["from"]["scale"] == "gsd"
    plain = resolve_settings(source, window=28).describe()
    assert plain["gsd"] == {"model": 0.04, "data": None} and plain["scale"] == 1.0


def test_gsd_needs_a_model_that_records_one_and_no_scale(model_files, with_gsd):
    with pytest.raises(UsageError, match="records no ground sampling distance"):
        resolve_settings(load_source(model_files["checkpoint"]), window=28, gsd=0.05)
    with pytest.raises(UsageError, match="give --gsd or --scale, not both"):
        resolve_settings(load_source(with_gsd), window=28, gsd=0.05, scale=0.5)


def test_the_onnx_document_carries_the_gsd():
    from claravid.eval.inference.sources import onnx_defaults
    from claravid.models.export.metadata import build_metadata, metadata_props, read_metadata

    record = {"metres_per_pixel": 0.031, "source": "data.gsd"}
    document = build_metadata({"backbone": "dinov2_vits14"}, patch_size=14, num_classes=8,
                              gsd=record)  # fmt: skip
    read = read_metadata(metadata_props(document))
    assert read["gsd"] == record
    assert onnx_defaults(read)["gsd"] == 0.031
    assert "gsd" not in onnx_defaults(build_metadata({}, patch_size=14, num_classes=8))
