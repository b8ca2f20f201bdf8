"""The package version, in a module of its own so that library modules (``_driver``) can
import it at module level while ``mpmjax/__init__.py`` is still importing them."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("mpmjax")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.1.0.dev0"
