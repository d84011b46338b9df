"""The root of mrswarm's errors, and the refusal of one piece of input that is counted.

Every error class of the project derives from :class:`MrswarmError`, besides the built-in
exception it already was (``ValueError``, ``OSError``...), so ``except ValueError`` still
catches what it caught, and ``except MrswarmError`` catches whatever mrswarm raised on purpose
(not a bug's ``TypeError``). A stop request (``mrswarm.run.signals.Interrupted``) is not an error
and stays outside.
"""

from __future__ import annotations


class MrswarmError(Exception):
    """An error mrswarm raises on purpose; its message says what is wrong (and what to do)."""


class Rejected(ValueError, MrswarmError):
    """A piece of input a receiver does not take: ``reason`` is the name of the counter it is
    counted under (``malformed``, ``bad_mac``...), ``detail`` what was wrong with it."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail
