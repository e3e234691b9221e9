"""Where the package's data files are: the installed share directory when
ament_index_python knows the package, else the source tree beside this module (no rclpy)."""

from pathlib import Path

PACKAGE_NAME = 'abp_description'

_SOURCE_ROOT = Path(__file__).resolve().parent.parent


def _share_dir():
    """Installed share/abp_description, or None when not installed (or no ament index)."""
    try:
        from ament_index_python.packages import get_package_share_directory
    except ImportError:
        return None
    try:
        return Path(get_package_share_directory(PACKAGE_NAME))
    except Exception:  # PackageNotFoundError and friends: not installed
        return None


def _data_file(subdir, name):
    candidates = []
    share = _share_dir()
    if share is not None:
        candidates.append(share / subdir / name)
    candidates.append(_SOURCE_ROOT / subdir / name)
    for path in candidates:
        if path.is_file():
            return path
    tried = ', '.join(str(p) for p in candidates)
    raise FileNotFoundError(f'{PACKAGE_NAME}: {subdir}/{name} not found (tried {tried})')
