# Strict TOML configuration: every key declared, typed and range-checked; every problem reported.
from __future__ import annotations

import copy
import difflib
import os
import tomllib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from base.config import BUILTIN, Config, ConfigError, SectionSettings
from base.options import Options, defaults
from daemon.components.control.kinematics import DiffDrive
from daemon.registry import COMPONENTS
from daemon.settings import CORE_SETTINGS, CORE_SETTINGS_LAST, LimitsSettings, RobotSettings
from drivers import DRIVERS, DriverError, MotorDriver, create_driver, driver_class
from drivers.base import renamed_hint
from drivers.devices import create_device

DEFAULT_PATH = Path("/etc/arbiterd/arbiterd.toml")
ENV_PREFIX = "ARBITERD_"


def _section_settings() -> dict[str, type[SectionSettings]]:
    """Section => its typed settings: the core sections, then each component's own."""
    table = {settings.SECTION: settings for settings in CORE_SETTINGS}
    for spec in COMPONENTS:
        if spec.settings is not None:
            if spec.settings.SECTION in table:
                raise ValueError(f"[{spec.settings.SECTION}] is declared twice")
            table[spec.settings.SECTION] = spec.settings
    table.update((settings.SECTION, settings) for settings in CORE_SETTINGS_LAST)
    return table


#: section => its typed settings class, derived from the component table
SETTINGS: dict[str, type[SectionSettings]] = _section_settings()
#: section => its Options
SECTIONS: dict[str, Options] = {name: settings.OPTIONS for name, settings in SETTINGS.items()}


def _section_aliases() -> dict[str, str]:
    """Old section name => the section it was renamed to (each settings class's ``aliases``)."""
    aliases: dict[str, str] = {}
    for section, settings in SETTINGS.items():
        for old in settings.ALIASES:
            if old in SETTINGS or old in aliases:
                raise ValueError(f"[{old}] is both a section and an old name of [{section}]")
            aliases[old] = section
    return aliases


#: old section name => its new name: a file or an environment variable using the old name still
#: loads, with a deprecation warning
ALIASES: dict[str, str] = _section_aliases()


class ConfigUnreadable(ConfigError):
    """The config file exists but this user may not read it (the installed service's config is
    root:arbiterd 0640 in a 0750 directory)."""

    def __init__(self, path: Path) -> None:
        super().__init__([f"{path}: cannot read it: permission denied ({_who_may_read(path)})"])
        self.path = path


def _who_may_read(path: Path) -> str:
    """``only root and the group 'arbiterd' may read it``, from the file or its directory."""
    for candidate in (path, path.parent):
        try:
            gid = candidate.stat().st_gid
        except OSError:
            continue
        try:
            import grp

            group = grp.getgrgid(gid).gr_name
        except KeyError:
            group = str(gid)
        if group != "root":
            return f"only root and the group {group!r} may read it"
    return "only root may read it"


def wheel_speed_clamp(config: Config) -> float:
    """The effective ``[robot] max_wheel_speed``, rad/s: as set, or (0) the fastest wheel speed
    the velocity limits can ask for."""
    robot, limits = config.get(RobotSettings), config.get(LimitsSettings)
    if robot.max_wheel_speed:
        return robot.max_wheel_speed
    return DiffDrive.from_settings(robot).max_wheel_speed(limits.linear_x_max_velocity,
                                                          limits.angular_z_max_velocity)


def build_driver(config: Config, name: str | None = None) -> MotorDriver:
    """The configured driver (or ``name``) from the registry, built (not opened) with the
    wheel-speed clamp; keys that are valid alone but clash are a :class:`ConfigError`."""
    name = name or config["driver"]["type"]
    try:
        return create_driver(name, config.driver_options(name),
                             max_wheel_speed=wheel_speed_clamp(config))
    except ValueError as exc:  # e.g. a pin used twice
        text = str(exc) if str(exc).startswith("[") else f"[driver.{name}] {exc}"
        raise ConfigError([f"{config.source}: {text}"]) from exc


def section_options(section: str) -> Options:
    """The Options table of a section, including ``driver.<name>`` subsections."""
    if section.startswith("driver."):
        return driver_class(section.split(".", 1)[1]).OPTIONS
    return SECTIONS[section]


def all_sections() -> list[str]:
    return [*SECTIONS, *(f"driver.{name}" for name in DRIVERS)]


def _section_tables(problems: list[str], used: set[str], source: str) -> dict[str, Options]:
    """Every section's Options; a driver module that cannot be imported is a problem only
    when its section is used."""
    tables: dict[str, Options] = {}
    for section in all_sections():
        try:
            tables[section] = section_options(section)
        except Exception as exc:
            if section in used:
                problems.append(f"{source}: [{section}]: {exc}")
    return tables


def load_config(path: Path | None = None, *, sim: bool = False,
                env: Mapping[str, str] | None = None, whole_robot: bool = False) -> Config:
    """Load and validate a config; raises :class:`ConfigError` listing every problem.

    ``path=None`` means the default path if it exists, else the built-in defaults, which run
    the simulated robot (with ``whole_robot``, what ``arbiterd run`` asks: :data:`WHOLE_ROBOT`
    on top of them). An explicit path must exist.
    """
    env = os.environ if env is None else env
    notes: list[str] = []
    raw, source, builtin = _read_source(path, sim, notes)
    if builtin and whole_robot:
        raw = copy.deepcopy(WHOLE_ROBOT)
    problems: list[str] = []
    raw = _renamed_sections(raw, source, problems, notes)
    flat = _flatten_file(raw, source, problems)
    tables = _section_tables(problems, set(flat), source)
    from_env = _apply_env(flat, env, tables, problems, notes)
    sections = _validate(flat, tables, source, problems, from_env)
    token = _read_token(sections.get("security", {}), source, problems)
    if problems:
        raise ConfigError(problems)
    config = Config(sections, source=source, sim=sim or builtin, token=token, warnings=notes)
    problems = _device_problems(config)
    if problems:
        raise ConfigError(problems)
    if config["control"]["cmd_vel_timeout"] == 0:
        config.warnings.append("[control] cmd_vel_timeout = 0: the deadman stop is DISABLED")
    return config


def _device_problems(config: Config) -> list[str]:
    """Each device a component's section makes it use, built from that section (not opened):
    keys valid alone but wrong together (two joints on one pin) are configuration errors."""
    problems = []
    for spec in COMPONENTS:
        for use in spec.devices_used(config):
            try:
                create_device(use.device, config[use.section], section=use.section)
            except (ValueError, DriverError) as exc:
                problems.append(f"{config.source}: {exc}")
    return problems


#: what ``arbiterd run --sim`` (and ``./install.sh sim``) runs without a config file: the whole
#: simulated robot in a furnished world, so every console panel works on first open. Each key
#: is an ordinary default underneath: ``ARBITERD_ARM_ENABLED=false`` turns the arm off.
WHOLE_ROBOT: dict[str, dict[str, Any]] = {
    "sim": {"world_file": "apartment"},
    "mapping": {"enabled": True},
    "arm": {"enabled": True, "backend": "pca9685"},
    "battery": {"enabled": True},
}


def whole_robot_toml() -> str:
    """:data:`WHOLE_ROBOT` as the TOML lines a config file of one's own would need."""
    lines = []
    for section, values in WHOLE_ROBOT.items():
        lines.append(f"[{section}]")
        lines += [f"{key} = {_toml_value(value)}" for key, value in values.items()]
    return "\n".join(lines) + "\n"


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return f'"{value}"' if isinstance(value, str) else str(value)


def _read_source(path: Path | None, sim: bool,
                 notes: list[str]) -> tuple[dict[str, Any], str, bool]:
    """The parsed file, its name, and whether the built-in defaults stand in for it."""
    default = path is None
    path = DEFAULT_PATH if path is None else path
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        if default:
            return {}, BUILTIN, True
        raise ConfigError([f"{path}: config file not found"]) from None
    except PermissionError:
        if default and sim:  # `run --sim` from a clone on a robot with the service installed
            notes.append(f"{path} is the installed service's config and this user may not "
                         f"read it ({_who_may_read(path)}): running the simulated robot on the "
                         "built-in defaults; pass --config FILE to use a config of your own")
            return {}, BUILTIN, True
        raise ConfigUnreadable(path) from None
    except OSError as exc:
        raise ConfigError([f"{path}: cannot read config file: {exc.strerror}"]) from None
    try:
        return tomllib.loads(text), str(path), False
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([f"{path}: not valid TOML: {exc}"]) from None


def _renamed_sections(raw: dict[str, Any], source: str, problems: list[str],
                      notes: list[str]) -> dict[str, Any]:
    """The file's sections with each old section name (:data:`ALIASES`) read as its new one,
    in place, and one deprecation warning for it; both names in one file are a problem."""
    for old, new in ALIASES.items():
        if old not in raw:
            continue
        if new in raw:
            problems.append(f"{source}: [{old}] and [{new}] are the same section ([{old}] is "
                            f"its old name): keep [{new}] only")
            raw = {name: table for name, table in raw.items() if name != old}
            continue
        notes.append(f"{source}: [{old}] is now [{new}]; rename the section in {source}")
        raw = {(new if name == old else name): table for name, table in raw.items()}
    return raw


def _flatten_file(raw: dict[str, Any], source: str,
                  problems: list[str]) -> dict[str, dict[str, Any]]:
    """Section -> {dotted key: value}; ``[driver.<name>]`` tables become their own sections."""
    known = set(all_sections())
    flat: dict[str, dict[str, Any]] = {}
    for name, table in raw.items():
        if name not in known or not isinstance(table, dict):
            what = "unknown section" if name not in known else "must be a table"
            problems.append(f"{source}: [{name}]: {what}; valid sections: "
                            f"{', '.join(sorted(SECTIONS))}")
            continue
        flat[name] = {}
        for key, value in _walk(table):
            sub = f"{name}.{key.split('.', 1)[0]}"
            if name == "driver" and sub in known and isinstance(table.get(key.split(".")[0]), dict):
                flat.setdefault(sub, {})[key.split(".", 1)[1]] = value
            else:
                flat[name][key] = value
    return flat


def _walk(table: Mapping[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    for key, value in table.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _walk(value, dotted + ".")
        else:
            yield dotted, value


def env_name(section: str, key: str) -> str:
    """``ARBITERD_<SECTION>_<KEY>`` with dots as underscores, upper case."""
    return (ENV_PREFIX + f"{section}_{key}".replace(".", "_")).upper()


def _apply_env(flat: dict[str, dict[str, Any]], env: Mapping[str, str],
               tables: dict[str, Options], problems: list[str],
               notes: list[str]) -> dict[tuple[str, str], str]:
    """Put the ``ARBITERD_<SECTION>_<KEY>`` overrides into ``flat``; returns which
    (section, key) each variable set, so a bad value is blamed on the variable. A variable
    under a section's old name (:data:`ALIASES`) still works, with a deprecation warning."""
    names = {env_name(section, key): (section, key)
             for section, options in tables.items() for key in options}
    old_names = {env_name(old, key): (old, new, key)
                 for old, new in ALIASES.items() for key in tables.get(new, {})}
    prefixes = tuple(env_name(section, "") for section in [*SECTIONS, *ALIASES])
    from_env: dict[tuple[str, str], str] = {}
    for var, text in env.items():
        if var in names:
            section, key = names[var]
        elif var in old_names:
            old, section, key = old_names[var]
            new_var = env_name(section, key)
            if new_var in env:
                problems.append(f"environment variables {var} and {new_var} both set "
                                f"[{section}] {key} ({var} is its old name): keep {new_var} "
                                "only")
                continue
            notes.append(f"environment variable {var}: [{old}] is now [{section}]; use "
                         f"{new_var}")
        else:
            if var.startswith(prefixes):
                close = difflib.get_close_matches(var, list(names), n=1, cutoff=0.8)
                hint = f" (did you mean {close[0]}?)" if close else ""
                problems.append(f"environment variable {var}: no such config key{hint}; the "
                                "overrides are ARBITERD_<SECTION>_<KEY>, e.g. "
                                "ARBITERD_HTTP_PORT")
            continue
        flat.setdefault(section, {})[key] = _parse_env_value(text)
        from_env[(section, key)] = f"{var}={text}"
    return from_env


def _parse_env_value(text: str) -> Any:
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _validate(flat: dict[str, dict[str, Any]], tables: dict[str, Options], source: str,
              problems: list[str],
              from_env: Mapping[tuple[str, str], str]) -> dict[str, dict[str, Any]]:
    sections: dict[str, dict[str, Any]] = {}
    for section, options in tables.items():
        values = defaults(options)
        for key, value in flat.get(section, {}).items():
            option = options.get(key)
            if option is None:
                problems.append(_unknown_key(source, section, key, options))
                continue
            value, err = option.validate(value)
            if err:
                where = (f"environment variable {from_env[(section, key)]}"
                         if (section, key) in from_env else source)
                problems.append(f"{where}: [{section}] {key}: {err}")
            values[key] = value
        if section in flat:
            problems += [f"{source}: {p}" for p in _cross_checks(section, values)]
        sections[section] = values
    return sections


def _cross_checks(section: str, values: dict[str, Any]) -> list[str]:
    """Problems between keys of one driver section (``check_options`` of the driver class)."""
    if not section.startswith("driver."):
        return []
    from drivers import driver_class

    check = getattr(driver_class(section.split(".", 1)[1]), "check_options", None)
    return list(check(values)) if check else []


def _unknown_key(source: str, section: str, key: str, options: Options) -> str:
    renamed = renamed_hint(key) if section.startswith("driver.") else None
    if renamed:
        return f"{source}: [{section}] {key}: {renamed}"
    close = difflib.get_close_matches(key, list(options), n=1, cutoff=0.7)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"{source}: [{section}] {key}: unknown key{hint}"


#: the shortest token accepted (the installer writes 43 characters: secrets.token_urlsafe(32))
MIN_TOKEN_CHARS = 12


def _read_token(security: Mapping[str, Any], source: str, problems: list[str]) -> str:
    token = _token_text(security, source, problems)
    if token and len(token) < MIN_TOKEN_CHARS:
        problems.append(f"{source}: [security] token: {len(token)} characters is too short to "
                        f"keep anyone out; at least {MIN_TOKEN_CHARS} (make one with `python3 "
                        f"-c 'import secrets; print(secrets.token_urlsafe(32))'`)")
        return ""
    return token


def _token_text(security: Mapping[str, Any], source: str, problems: list[str]) -> str:
    token, token_file = security.get("token", ""), security.get("token_file", "")
    if token and token_file:
        problems.append(f"{source}: [security]: set token or token_file, not both")
        return ""
    if not token_file:
        return str(token)
    try:
        lines = Path(token_file).read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        problems.append(f"{source}: [security] token_file: cannot read {token_file}: "
                        f"{exc.strerror}")
        return ""
    if not lines or not lines[0].strip():
        problems.append(f"{source}: [security] token_file: {token_file} is empty")
        return ""
    return lines[0].strip()
