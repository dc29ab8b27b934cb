"""Built-in robot, human and task plugins, installed as ``hritest_plugins``.

They are registered in the ``hritest.plugins`` entry-point group by hritest's own
``pyproject.toml`` and loaded through the same mechanism as a user's plugin.
"""
