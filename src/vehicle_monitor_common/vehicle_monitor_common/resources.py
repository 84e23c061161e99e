"""Files a package ships (scenarios, configs): found in its installed share directory.

On a ROS install the share directory is all there is; in this workspace's source tree (tools
running before a build) the package folder under ``src/`` holds the same files. No ROS runtime
import: offline tools use it too.
"""

from __future__ import annotations

from pathlib import Path

_SOURCE_ROOT = Path(__file__).resolve().parents[2]


def share_dir(package: str, subdir: str) -> Path:
    """``share/<package>/<subdir>`` of the installed package, else ``src/<package>/<subdir>``."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
        try:
            installed = Path(get_package_share_directory(package)) / subdir
            if installed.is_dir():
                return installed
        except (PackageNotFoundError, ValueError, OSError):
            pass  # not installed, or AMENT_PREFIX_PATH unset: use the source tree
    except ImportError:
        pass
    return _SOURCE_ROOT / package / subdir


def shipped_file(package: str, subdir: str, name: str, suffix: str = '.yaml') -> Path:
    """A file the package ships, by name (``'puncture_15pct_fl'``) or as an existing path.

    Raises:
        FileNotFoundError: naming what is available.
    """
    candidate = Path(name)
    if candidate.is_file():
        return candidate
    directory = share_dir(package, subdir)
    path = directory / (name if name.endswith(suffix) else name + suffix)
    if path.is_file():
        return path
    available = ', '.join(sorted(p.stem for p in directory.glob(f'*{suffix}')))
    raise FileNotFoundError(f'no file {name!r}, nor one of that name in {package}/{subdir} '
                            f'(available: {available})')


def workspace_bags() -> Path:
    """The shipped scenario bags: ``<workspace>/bags`` beside the packages, whether they run
    from the source tree or from the colcon install space inside it; else ``./bags``."""
    for parent in Path(__file__).resolve().parents:
        if (parent / 'bags').is_dir():
            return parent / 'bags'
    return Path('bags')
