"""Every error class of the toolkit crosses a process boundary intact.

``multiprocessing`` (``claravid-cache --workers N``, the DSP pool) pickles an error; torch's
DataLoader rebuilds a worker's error as ``type(error)(text)`` with one argument, and falls back to
a bare ``RuntimeError`` (a traceback, exit 1) for a class that cannot be built so. The classes are
found by importing every module of the project, so a new one is checked without being listed.
"""

import importlib
import pickle
import pkgutil

import pytest
from torch.utils.data import DataLoader, Dataset

from claravid.data.cache_entries import CacheWriteError
from claravid.data.splits import SplitConfigError
from claravid.dsp.metrics import ImageReadError
from claravid.infra.cli import run_cli
from claravid.infra.errors import CorruptFileError, DatasetNotFoundError, UnsupportedFileError

PACKAGES = ["claravid", "claravid.models", "claravid.train", "claravid.eval", "claravid.configs"]


def project_exception_classes():
    found = set()
    for name in PACKAGES:
        package = importlib.import_module(name)
        modules = [name] + [
            m.name
            for m in pkgutil.walk_packages(package.__path__, f"{name}.")
            if not m.name.endswith("__main__")
        ]
        for module_name in modules:
            module = importlib.import_module(module_name)
            for value in vars(module).values():
                if (
                    isinstance(value, type)
                    and issubclass(value, BaseException)
                    and value.__module__ == module_name
                ):
                    found.add(value)
    return sorted(found, key=lambda c: f"{c.__module__}.{c.__qualname__}")


CLASSES = project_exception_classes()


def example(cls, tmp_path):
    """An instance as the project raises it: the full constructor where it takes more."""
    made_with_more = {
        DatasetNotFoundError: lambda: DatasetNotFoundError(
            "ClaraVid root", tmp_path / "nowhere", "download it first"
        ),
        CorruptFileError: lambda: CorruptFileError(tmp_path / "a b.jpg", "truncated JPEG"),
        UnsupportedFileError: lambda: UnsupportedFileError(tmp_path / "x.jpg", "12-bit JPEG"),
        ImageReadError: lambda: ImageReadError(tmp_path / "y.png", "no such file"),
        SplitConfigError: lambda: SplitConfigError("split_config.seed", "must be >= 0, got -1"),
        CacheWriteError: lambda: CacheWriteError(
            f"no space left writing {tmp_path / 'c' / 'x.tif'}", 3, "set CLARAVID_CACHE"
        ),
    }
    if cls in made_with_more:
        return made_with_more[cls]()
    assert "__init__" not in vars(cls) and "__new__" not in vars(cls), (
        f"{cls.__module__}.{cls.__qualname__} has its own constructor: add an example here"
    )
    return cls(f"{cls.__name__} says what went wrong")


def test_the_project_has_the_error_classes_we_know_of():
    names = {c.__name__ for c in CLASSES}
    # The walk reaches every installed package, including models/, train/ and eval/.
    assert {"CorruptFileError", "CheckpointError", "TrainingDiverged", "UnitError"} <= names
    assert {"DatasetNotFoundError", "ImageReadError", "SplitConfigError", "UsageError"} <= names


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__qualname__)
def test_pickle_round_trip_keeps_type_message_and_attributes(cls, tmp_path):
    error = example(cls, tmp_path)
    again = pickle.loads(pickle.dumps(error))
    assert type(again) is cls
    assert str(again) == str(error) and again.args == error.args
    assert vars(again) == vars(error)


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__qualname__)
def test_one_argument_construction_is_the_same_error(cls, tmp_path):
    message = str(example(cls, tmp_path))
    rebuilt = cls(message)
    assert type(rebuilt) is cls and str(rebuilt) == message


def test_the_full_constructors_still_write_their_messages(tmp_path):
    corrupt = CorruptFileError(tmp_path / "f.jpg", "truncated JPEG")
    assert (
        str(corrupt)
        == f"cannot read {tmp_path / 'f.jpg'}: truncated JPEG; re-copy or re-extract the file"
    )
    assert corrupt.path == tmp_path / "f.jpg" and corrupt.reason == "truncated JPEG"
    unsupported = UnsupportedFileError("f.jpg", "12-bit JPEG; convert it to 8 bits")
    assert str(unsupported) == "cannot read f.jpg: 12-bit JPEG; convert it to 8 bits"
    assert isinstance(unsupported, CorruptFileError)
    missing = DatasetNotFoundError("ClaraVid root", tmp_path / "nowhere")
    assert (
        str(missing)
        == f"ClaraVid root not found: searched {tmp_path / 'nowhere'}; {tmp_path} is empty"
    )
    rebuilt = CorruptFileError(str(corrupt))
    assert rebuilt.path is None and rebuilt.reason == str(corrupt)


class _Broken(Dataset):
    def __len__(self):
        return 2

    def __getitem__(self, index):
        raise CorruptFileError(
            f"/data/frame {index}.jpg", "truncated JPEG (no end-of-image marker)"
        )


def _load(args):
    for _ in DataLoader(_Broken(), batch_size=1, num_workers=args.workers):
        pass


@pytest.mark.parametrize("workers", [0, 1])
def test_an_error_of_a_dataloader_worker_is_one_line_exit_2(workers, capsys):
    import argparse

    parser = argparse.ArgumentParser(prog="claravid-x")
    parser.add_argument("--workers", type=int)
    assert run_cli("claravid-x", _load, parser, ["--workers", str(workers)]) == 2
    err = capsys.readouterr().err
    assert err == (
        "claravid-x: error: cannot read /data/frame 0.jpg: truncated JPEG (no end-of-image "
        "marker); re-copy or re-extract the file\n"
    )


def test_the_worker_error_arrives_as_its_own_class():
    with pytest.raises(CorruptFileError, match=r"Caught CorruptFileError in DataLoader worker"):
        for _ in DataLoader(_Broken(), batch_size=1, num_workers=1):
            pass
