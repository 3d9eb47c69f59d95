"""Errors a user can act on: each carries one line saying what is wrong and what to do."""


class KosmapError(Exception):
    """Base for errors that the CLI prints as one line and exits non-zero (never a traceback)."""

    exit_code = 2


class LogError(KosmapError):
    """A log that cannot be read: missing, not a log, truncated, unsupported content."""


class ConfigError(KosmapError):
    """A configuration key that does not exist or a value out of its range."""


class TopicError(KosmapError):
    """A requested topic that the log does not have, or no usable topic at all."""
