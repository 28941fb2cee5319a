"""The configuration of a ``tof-fpn clean`` run, generated from the steps' declared options.

A run is described by a :class:`CleanConfig`, read from a small TOML file (:func:`load_config`,
Python's ``tomllib``), from command-line flags, or both (flags win). Its options are those of the
registered steps (:mod:`tof_fpn_torch.clean.steps`: the fixed pattern, the FPN stage, flying
pixels, the denoiser, temporal filtering) and of the run itself
(:data:`~tof_fpn_torch.clean.steps.FILE_OPTIONS`: files, batches, calibration frames); each is
declared once, with its type, default, allowed values and a one-line description, and the
TOML tables, the command-line flags and :func:`reference` (the annotated file) follow from the
declarations. The resolved configuration is saved beside the output as ``clean.toml`` together
with the package version (:func:`config_to_toml`); a saved file is itself a valid ``--config``.
``python -c "from tof_fpn_torch.clean.config import reference; print(reference())"`` prints every
key with its default and description.

``auto`` / ``data`` stages are measured on the calibration frames when the run starts
(:mod:`tof_fpn_torch.build`: ``broadband_from_data``, ``suppression_from_data``,
``fusion_from_data``); ``[tof_fpn_torch]`` (the version a saved file records) is accepted and not
used. A key given explicitly wins over the ``stage`` preset.

**Integer outputs.** A uint16-mm file cannot hold a correction of 0.3 mm by rounding to the
nearest millimetre: it rounds back to the input. ``rounding = "dither"`` (default) rounds each
valid pixel up with probability equal to its fractional part (a uniform dither from a generator
seeded by the frame's own bytes, so the same input gives the same bytes): every column, row and
region keeps the corrected mean, at the price of a rounding noise of variance ``f (1 - f)``
(<= 1/4 unit^2, 1/6 on average) instead of nearest rounding's 1/12 (and pixels the stage did not
move keep their value exactly). ``output_scale`` stores the depth in finer units instead (e.g.
0.1 mm: a uint16 then reaches 6.5535 m); the files then no longer hold millimetres, so a reader
must be told the scale (the manifest records it, and a PNG gets a ``depth_scale_m`` text chunk).

Example:
    >>> CleanConfig(stage="paper").notch, CleanConfig(notch="off").fusion
    ('design', 'off')
"""

from __future__ import annotations

from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser as a package
    import tomli as tomllib

from .. import __version__
from .steps import FILE_OPTIONS, Option, TableOption, options, steps
from .steps.files import BATCH, CALIBRATION_FRAMES

__all__ = [
    "BATCH",
    "CALIBRATION_FRAMES",
    "CleanConfig",
    "all_options",
    "choices",
    "config_from_dict",
    "config_to_toml",
    "load_config",
    "reference",
]


def all_options() -> dict[str, Option | TableOption]:
    """Every option of a run by name: the registered steps' in step order, then the run's own."""
    return {o.name: o for o in [*options(), *FILE_OPTIONS]}


def choices() -> dict[str, tuple]:
    """The allowed values of each option that has a fixed set of them."""
    return {
        o.name: o.setting.choices
        for o in all_options().values()
        if isinstance(o, Option) and o.setting.choices
    }


def _tables() -> dict[str, dict[str, str]]:
    """TOML table -> {key: option name}, ``[pipeline]`` first, then in the order of the options."""
    out: dict[str, dict[str, str]] = {"pipeline": {}}
    for o in all_options().values():
        if isinstance(o, Option):
            out.setdefault(o.table, {})[o.key] = o.name
    return out


def _free_tables() -> dict[str, str]:
    """TOML table -> option name of the tables of free keys (:class:`TableOption`)."""
    return {o.table: o.name for o in all_options().values() if isinstance(o, TableOption)}


class CleanConfig:
    """What a ``tof-fpn clean`` run does: one keyword per declared option (:func:`reference`),
    each an attribute; unset options take their defaults and the steps' presets.

    Raises:
        TypeError: an unknown keyword.
        ValueError: a value the option does not allow (the message names the option, what was
            given and what is allowed), or options that do not go together.
    """

    def __init__(self, **values) -> None:
        known = all_options()
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise TypeError(f"CleanConfig got unknown option(s) {unknown}; known: {sorted(known)}")
        v: dict = {}
        for name, o in known.items():
            given = values.get(name)
            if isinstance(o, TableOption):
                v[name] = {} if given is None else given
                if isinstance(v[name], dict):
                    v[name] = dict(v[name])
                continue
            v[name] = o.setting.default if name not in values else given
            if v[name] is not None:
                v[name] = o.setting.check(v[name])
        for step in steps():
            if step.resolve is not None:
                step.resolve(v)
        object.__setattr__(self, "_values", v)

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        try:
            return self._values[name]
        except KeyError:
            raise AttributeError(f"CleanConfig has no option {name!r}") from None

    def __setattr__(self, name: str, value) -> None:
        raise AttributeError("a CleanConfig is not changed in place: use replace(...)")

    def __eq__(self, other) -> bool:
        return isinstance(other, CleanConfig) and self._values == other._values

    def __repr__(self) -> str:
        items = ", ".join(f"{k}={v!r}" for k, v in self._values.items())
        return f"CleanConfig({items})"

    def values(self) -> dict:
        """Every option's value (a copy)."""
        return {k: (dict(v) if isinstance(v, dict) else v) for k, v in self._values.items()}

    def replace(self, **changes) -> CleanConfig:
        """A copy with ``changes`` (checked again); ``None`` values are ignored (flag not given);
        a step may move its other options with a change (a new ``stage`` preset, say)."""
        changes = {k: v for k, v in changes.items() if v is not None}
        for step in steps():
            if step.on_replace is not None:
                step.on_replace(self._values, changes)
        return CleanConfig(**{**self.values(), **changes})

    def identity(self) -> str:
        """What decides the output bytes (everything here): two runs into one OUTPUT must agree."""
        return config_to_toml(self, version=False)


def config_from_dict(data: dict, where: str = "config") -> CleanConfig:
    """A :class:`CleanConfig` from parsed TOML; unknown tables or keys raise ``ValueError``."""
    tables, free = _tables(), _free_tables()
    kwargs: dict = {}
    for table, values in data.items():
        if table == "tof_fpn_torch":
            continue
        if table in free:
            if not isinstance(values, dict):
                raise ValueError(f"{where}: [{table}] must be a table, got {values!r}")
            kwargs[free[table]] = dict(values)
            continue
        if table not in tables or not isinstance(values, dict):
            raise ValueError(
                f"{where}: unknown table {table!r}; allowed: {sorted([*tables, *free])}"
            )
        for key, value in values.items():
            if key not in tables[table]:
                raise ValueError(
                    f"{where}: unknown key {key!r} in [{table}]; allowed: {sorted(tables[table])}"
                )
            kwargs[tables[table][key]] = value
    try:
        return CleanConfig(**kwargs)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def load_config(path) -> CleanConfig:
    """Read a TOML configuration file (format: :func:`reference`)."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"config file not found: {path}")
    try:
        data = tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"config {path}: not valid TOML: {exc}") from None
    return config_from_dict(data, f"config {path}")


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and v in (float("inf"), float("-inf")):
        return "inf" if v > 0 else "-inf"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    raise ValueError(f"cannot write {v!r} ({type(v).__name__}) to TOML")


def config_to_toml(config: CleanConfig, version: bool = True) -> str:
    """The configuration as TOML (absent values left out), headed by ``[tof_fpn_torch] version``
    when ``version``; :func:`load_config` reads it back to an equal :class:`CleanConfig`."""
    lines = []
    if version:
        lines += ["[tof_fpn_torch]", f"version = {_toml_value(__version__)}", ""]
    values = config.values()
    for table, keys in _tables().items():
        lines.append(f"[{table}]")
        for key, name in keys.items():
            v = values[name]
            if v is not None:
                lines.append(f"{key} = {_toml_value(v)}")
        lines.append("")
    for table, name in _free_tables().items():
        lines.append(f"[{table}]")
        free = values[name]
        for key in sorted(free):
            lines.append(f"{key} = {_toml_value(free[key])}")
    return "\n".join(lines) + "\n"


def reference() -> str:
    """The TOML format, every key with its default and description (generated from the
    declared options)."""
    lines = []
    by_table: dict[str, list] = {}
    for o in all_options().values():
        by_table.setdefault(o.table, []).append(o)
    for table in ["pipeline", *[t for t in by_table if t != "pipeline"]]:
        lines.append(f"[{table}]")
        for o in by_table.get(table, []):
            if isinstance(o, TableOption):
                lines.append(f"# KEY = VALUE   # {o.help}")
                continue
            s = o.setting
            default = "(absent)" if s.default is None else _toml_value(s.default)
            lines.append(f"{o.key} = {default}   # {s.help}; {s.allowed()}")
        lines.append("")
    return "\n".join(lines)
