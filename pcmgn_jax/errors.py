"""The library's refusal of a setting: :class:`SettingError` names the setting; the command line names its flag.

A library function that refuses a value it was given raises ``SettingError(name, why)``: in a script it reads
``name: why`` (the keyword or field the caller passed), and :func:`pcmgn_jax.cli.run` prints it as
``error: --name: why``, the flag the command line took it from. The library never spells a flag itself.
"""
from __future__ import annotations


class SettingError(ValueError):
    """A refused setting: ``name`` (the keyword / config field, which is also the flag's name) and ``why`` (what is
    wrong with its value, naming the value, the file or the folder)."""

    def __init__(self, name: str, why: str):
        super().__init__(f"{name}: {why}")
        self.name, self.why = name, why

    def as_flag(self) -> str:
        """The message as the command line says it: ``--name: why``."""
        return f"--{self.name}: {self.why}"
