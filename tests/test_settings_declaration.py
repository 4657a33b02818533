# Each config key is declared once, as a settings field: the option tables are made from the fields.
from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass
from typing import Any

import pytest

from base.config import SectionSettings
from base.options import DECLARATION, Option, defaults, kind_of, option, options_of
from daemon.config import SETTINGS
from daemon.registry import COMPONENTS
from drivers import DRIVERS, driver_class
from drivers.device_registry import DEVICES


def _device_class(name: str) -> Any:
    module, cls = DEVICES[name]
    return getattr(importlib.import_module(module), cls)


#: every settings class a table is made from: the sections, each driver's, each device's
DECLARED: dict[str, type[Any]] = {
    **{f"[{section}]": settings for section, settings in SETTINGS.items()},
    **{f"[driver.{name}]": driver_class(name).SETTINGS for name in DRIVERS},
    **{f"device {name}": _device_class(name).SETTINGS for name in DEVICES},
}
#: ... and the classes whose OPTIONS are those tables
TABLES: dict[str, Any] = {
    **{f"[{section}]": settings for section, settings in SETTINGS.items()},
    **{f"[driver.{name}]": driver_class(name) for name in DRIVERS},
    **{f"device {name}": _device_class(name) for name in DEVICES},
}


@pytest.mark.parametrize("spec", [s for s in COMPONENTS if s.settings is not None],
                         ids=lambda s: s.name)
def test_a_components_section_is_named_after_it(spec: Any) -> None:
    """Folder = component name = config section (components without settings are exempt)."""
    assert spec.create.__module__ == f"daemon.components.{spec.name}.component"
    assert spec.name == spec.settings.SECTION
    assert spec.name not in spec.settings.ALIASES


def test_an_old_section_name_is_no_section_of_its_own() -> None:
    from daemon.config import ALIASES

    assert ALIASES == {"record": "recorder"}
    assert not set(ALIASES) & set(SETTINGS)


@pytest.mark.parametrize("where", list(DECLARED))
def test_the_option_table_comes_from_the_fields_only(where: str) -> None:
    settings, table = DECLARED[where], TABLES[where].OPTIONS
    assert dataclasses.is_dataclass(settings) and settings.__dataclass_params__.frozen
    fields = dataclasses.fields(settings)
    assert all(DECLARATION in f.metadata for f in fields), "declare each field with option()"
    assert [key.replace(".", "_") for key in table] == [f.name for f in fields]
    assert table == options_of(settings)
    assert settings() == settings(**{f.name: v for f, v in zip(fields, defaults(table).values(),
                                                                strict=True)})
    for f, (key, declared) in zip(fields, table.items(), strict=True):
        kind, item = kind_of(f.type)
        assert declared.kind is kind and declared.item is (item or declared.item), key
        assert isinstance(declared.doc, str) and declared.doc, key


def test_no_module_declares_a_table_beside_the_fields() -> None:
    """The ``*_OPTIONS`` dicts are gone: a section's keys are its settings class's fields."""
    for settings in SETTINGS.values():
        module = importlib.import_module(settings.__module__)
        tables = [name for name, value in vars(module).items()
                  if name.endswith("_OPTIONS") and isinstance(value, dict)]
        assert not tables, f"{settings.__module__}: {tables}"
    with pytest.raises(TypeError):
        type("Old", (SectionSettings,), {}, section="old", options={})


# -- the generator --------------------------------------------------------------------------------

@dataclass(frozen=True)
class Sample(SectionSettings, section="sample"):
    mode: str = option("off", "what it does", choices=("off", "on"))
    speed: float = option(0.5, "how fast, m/s", above=0.0, maxval=5.0)
    count: int = option(3, "how many", minval=1)
    linear_x_limit: float = option(1.0, "a dotted key", key="linear.x.limit", minval=0.0)
    names: list[str] = option(["a"], "names")
    poses: list[list[Any]] = option([], "nested lists")
    flags: list[bool] = option([], "one per name", length=None)


def test_kind_item_bounds_and_keys_come_from_the_declaration() -> None:
    table = Sample.OPTIONS
    assert list(table) == ["mode", "speed", "count", "linear.x.limit", "names", "poses", "flags"]
    assert table["mode"] == Option(str, "off", "what it does", choices=("off", "on"))
    assert table["speed"] == Option(float, 0.5, "how fast, m/s", above=0.0, maxval=5.0)
    assert table["count"] == Option(int, 3, "how many", minval=1)
    assert table["linear.x.limit"] == Option(float, 1.0, "a dotted key", minval=0.0)
    assert table["names"] == Option(list, ["a"], "names", item=str)
    assert table["poses"].item is list and table["flags"].item is bool
    assert Sample.OPTIONS is table  # made once, on first use
    assert Sample().linear_x_limit == 1.0
    assert Sample.from_values({"linear.x.limit": 2.0}).linear_x_limit == 2.0


def test_a_list_default_is_not_shared_between_instances() -> None:
    first, second = Sample(), Sample()
    assert first.names == second.names == ["a"] and first.names is not second.names
    assert Sample.OPTIONS["names"].default == ["a"]


@pytest.mark.parametrize(("body", "message"), [
    pytest.param({"__annotations__": {"x": "int"}, "x": 1}, "declare the field with option",
                 id="plain default"),
    pytest.param({"__annotations__": {"x_y": "float"}, "x_y": option(1.0, "d", key="x.z")},
                 "does not match", id="key and name differ"),
    pytest.param({"__annotations__": {"x": "int"}, "x": option(0, "d", minval=1)},
                 "must be >= 1", id="default out of its bounds"),
    pytest.param({"__annotations__": {"x": "int"}, "x": option("0", "d")},
                 "expected an integer", id="default of the wrong kind"),
    pytest.param({"__annotations__": {"x": "dict[str, int]"}, "x": option(0, "d")},
                 "not dict", id="no config kind"),
])
def test_a_bad_declaration_names_the_class_and_field(body: dict[str, Any], message: str) -> None:
    settings = dataclass(frozen=True)(type("Bad", (), body))
    with pytest.raises(TypeError, match=message) as info:
        options_of(settings)
    assert "Bad." in str(info.value)


def test_kind_of_reads_text_and_types() -> None:
    assert kind_of("float") == (float, None) and kind_of(bool) == (bool, None)
    assert kind_of("list[int]") == (list, int) and kind_of(list[str]) == (list, str)
    assert kind_of("list[list[Any]]") == (list, list) and kind_of("list[Any]") == (list, None)
