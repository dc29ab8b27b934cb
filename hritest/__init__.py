"""hritest: find where a robot policy fails with people, and keep those failures as tests."""

__version__ = "0.1.0"
