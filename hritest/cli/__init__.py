"""The ``hritest`` command (``hritest.cli:app``): the app in :mod:`.app`, its commands in
:mod:`.specs` and :mod:`.runs`, which register themselves on import."""

from hritest.cli import specs, runs  # noqa: F401, I001 - importing registers the commands, in this order in --help
from hritest.cli.app import ExitCode, app

__all__ = ["ExitCode", "app"]
