"""setuptools' entry beside pyproject.toml (which holds the configuration): one fix for editable installs."""

from setuptools import setup
from setuptools.dist import Distribution


class _Distribution(Distribution):
    """The project's distribution: answers `has_data` as well as `has_data_files`."""

    def has_data(self) -> bool:
        """True when there are data files: setuptools' editable install (`pip install -e`) installs them only
        when the distribution answers `has_data` (pypa/setuptools#3399), and they carry the official names'
        startup .pth (pyproject.toml, `tool.setuptools.data-files`), which editable installs need as wheels do."""
        return self.has_data_files()


setup(distclass=_Distribution)
