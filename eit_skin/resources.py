"""Files shipped with the package (patch configs), found installed or in the source tree."""

from __future__ import annotations

from pathlib import Path

PACKAGE = "eit_skin"
SOURCE_CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"


def config_dir() -> Path:
    """Directory of the shipped configs: the ament share dir if installed, else ``config/``."""
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )
    except ImportError:
        return SOURCE_CONFIG_DIR
    try:
        share = Path(get_package_share_directory(PACKAGE)) / "config"
    except (PackageNotFoundError, LookupError, ValueError, OSError):
        return SOURCE_CONFIG_DIR
    return share if share.is_dir() else SOURCE_CONFIG_DIR


def config_path(name_or_path: str | Path) -> Path:
    """Path of a patch file: an existing path as given, else a shipped config by name.

    ``"arm"``, ``"face"``, ``"elbow"`` (or ``"arm.yaml"``) name the shipped patches.  A name
    that matches nothing is returned unchanged so the caller reports the missing file.
    """
    path = Path(name_or_path)
    if path.exists() or len(path.parts) > 1:
        return path
    file_name = path.name if path.suffix in (".yaml", ".yml") else f"{path.name}.yaml"
    for directory in (config_dir(), SOURCE_CONFIG_DIR):
        candidate = directory / file_name
        if candidate.is_file():
            return candidate
    return path
