"""signpose's computer vision: framework-free stages over numpy arrays (numpy + OpenCV only)."""

from pathlib import Path


def shipped_folder(package_dir: Path, name: str) -> Path:
    """The folder `name` shipped with signpose (static, sample_images) for the package at `package_dir`.

    It lives at the top of the source checkout, where the tools, tests and docs use it, and is found
    there when signpose runs from the checkout or an editable install (pip install -e). An installed
    copy (pip install .) has no checkout: pyproject.toml packs the folder inside the package instead.
    """
    installed = package_dir / name
    return installed if installed.is_dir() else package_dir.parent / name
