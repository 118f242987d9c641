"""Paths for the tests: run by ctest (Python.pytest) with PYTHONPATH at the
build tree's python/ and OTFP at the command-line tool."""
import os
import pathlib

import pytest

SOURCE_DIR = pathlib.Path(os.environ.get("OTFP_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))


@pytest.fixture
def source_dir():
    return SOURCE_DIR


@pytest.fixture
def otfp_cli():
    path = os.environ.get("OTFP")
    if not path:
        pytest.skip("OTFP (the otfp binary) is not set; ctest sets it")
    return path
