"""``python -m hritest.cli``: the hritest command."""

from hritest.cli import app

app()
