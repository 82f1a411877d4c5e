"""Shared fixtures. Nothing may reach a hub: Hugging Face is offline with a private cache."""

from __future__ import annotations

import atexit
import os
import shutil
import signal
import tempfile
from pathlib import Path

import pytest
from support import TESTDATA

os.environ["HF_HUB_OFFLINE"] = "1"
if "HF_HOME" not in os.environ:  # a private one, removed when the run ends (its test processes inherit it)
    os.environ["HF_HOME"] = tempfile.mkdtemp(prefix="imitation-tests-hf-")
    atexit.register(shutil.rmtree, os.environ["HF_HOME"], ignore_errors=True)

# A script's background job starts with SIGINT ignored, and its children would inherit that: the
# Ctrl-C tests need it delivered, as in a terminal.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def testdata() -> Path:
    """../shared/testdata: third-party files, present beside the repo in CI, absent in user clones."""
    if not TESTDATA.is_dir():
        pytest.skip(f"third-party test data not found at {TESTDATA} (only present beside the project's checkout)")
    return TESTDATA
