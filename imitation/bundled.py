"""Where the bundled demonstration files (datasets/*.mcap) are."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

_SOURCE_ROOT = Path(__file__).resolve().parent.parent


def bundled_datasets() -> Path:
    """The folder that holds the bundled .mcap files.

    Two places, because the files live in one folder of the repository but ship inside the
    package: in a source checkout (and in its editable install) they are the top-level
    datasets/ beside imitation/, which stays data only so as not to shadow Hugging Face
    `datasets`; a wheel or sdist install (`pip install .`) carries them as the data-only
    package `imitation.datasets` (pyproject.toml maps datasets/ onto it), found here with
    importlib.resources, since there is no repository beside site-packages/imitation/ then
    (and site-packages/datasets/ is Hugging Face's package, not ours).
    """
    installed = files("imitation") / "datasets"
    if isinstance(installed, Path) and installed.is_dir():
        return installed
    source = _SOURCE_ROOT / "datasets"
    if (_SOURCE_ROOT / "pyproject.toml").is_file() and source.is_dir():
        return source
    # Neither (a broken install): the installed location, for the caller's "not found" message.
    return Path(str(installed))
