"""How a config setting says what it accepts: :class:`Rule`, the common rules and :func:`setting`.

The schema (:mod:`torchrl_mbe.app.config`, and each explorer's in
:mod:`torchrl_mbe.app.explorers`) declares every field with :func:`setting`, so its
default and its rule stand together; :func:`~torchrl_mbe.app.config.check_config`
applies the rules and raises :class:`ConfigError`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from torchrl_mbe.rundir import is_int, is_number

__all__ = [
    "ANY",
    "DISCOUNT",
    "FRACTION",
    "LAYERS",
    "NON_NEGATIVE",
    "NON_NEGATIVE_INT",
    "POSITIVE",
    "POSITIVE_INT",
    "PROBABILITY",
    "ConfigError",
    "Rule",
    "one_of",
    "setting",
]


class ConfigError(ValueError):
    """A config value the app cannot run with; the message names the key and what is accepted."""


@dataclass(frozen=True)
class Rule:
    """What a setting accepts: a test and the words that describe it."""

    test: Callable[[Any], bool]
    accepted: str

    def or_none(self) -> Rule:
        return Rule(lambda v: v is None or self.test(v), f"{self.accepted}, or null")


POSITIVE_INT = Rule(lambda v: is_int(v) and v >= 1, "a positive integer")
NON_NEGATIVE_INT = Rule(lambda v: is_int(v) and v >= 0, "an integer >= 0")
NON_NEGATIVE = Rule(lambda v: is_number(v) and v >= 0, "a number >= 0")
POSITIVE = Rule(lambda v: is_number(v) and v > 0, "a number > 0")
PROBABILITY = Rule(lambda v: is_number(v) and 0 <= v <= 1, "a number in [0, 1]")
DISCOUNT = Rule(lambda v: is_number(v) and 0 <= v <= 1, "a discount in [0, 1]")
FRACTION = Rule(lambda v: is_number(v) and 0 < v <= 1, "a number in (0, 1]")
LAYERS = Rule(lambda v: len(v) > 0 and all(is_int(c) and c >= 1 for c in v), "a non-empty list of positive layer sizes")
ANY = Rule(lambda v: True, "anything")


def one_of(*options: str) -> Rule:
    return Rule(lambda v: v in options, "one of " + ", ".join(options))


def setting(default: Any, rule: Rule = ANY) -> Any:
    """A dataclass field with its default and the :class:`Rule` its values must pass."""
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata={"rule": rule})
    return field(default=default, metadata={"rule": rule})
