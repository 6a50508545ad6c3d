"""The quick construction of the frozen state classes (companion.vehicle_state): the same
objects as their constructors build, frozen like them."""

import dataclasses
import inspect
import pickle

import pytest

from fpv_station.companion import vehicle_state
from fpv_station.companion.vehicle_state import (
    Attitude,
    PilotAltitude,
    VehicleMessage,
    VehicleState,
    freeze_draft,
    quick_constructor,
    quick_replace,
    unfrozen_twin,
)

FROZEN = [
    cls
    for _, cls in inspect.getmembers(vehicle_state, inspect.isclass)
    if cls.__module__ == vehicle_state.__name__ and dataclasses.is_dataclass(cls)
]


def sample(cls: type) -> dict[str, object]:
    """Every field given, each a value of its own (no default in sight)."""
    values: dict[str, object] = {}
    for i, f in enumerate(dataclasses.fields(cls)):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if dataclasses.is_dataclass(default):
            values[f.name] = default
        elif isinstance(default, tuple):
            values[f.name] = (i,) * 3
        elif f.type.startswith("str"):
            values[f.name] = f"text {i}"
        elif f.type.startswith("bool"):
            values[f.name] = True
        else:
            values[f.name] = i + 0.5
    return values


def test_every_state_class_is_frozen_with_slots():
    assert len(FROZEN) >= 14, FROZEN
    for cls in FROZEN:
        assert cls.__dataclass_params__.frozen and hasattr(cls, "__slots__"), cls


@pytest.mark.parametrize("cls", FROZEN, ids=lambda c: c.__name__)
def test_quick_constructor_builds_the_class_own_frozen_object(cls):
    values = sample(cls)
    slow = cls(**values)
    for quick in (
        quick_constructor(cls)(**values),
        quick_constructor(cls)(*values.values()),
        freeze_draft(unfrozen_twin(cls)(**values), cls),
    ):
        assert type(quick) is cls
        assert quick == slow and hash(quick) == hash(slow) and repr(quick) == repr(slow)
        assert dataclasses.asdict(quick) == dataclasses.asdict(slow)
        assert pickle.loads(pickle.dumps(quick)) == slow
        name = dataclasses.fields(cls)[0].name
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(quick, name, None)
        with pytest.raises((AttributeError, TypeError)):
            quick.not_a_field = 1  # no __dict__: slots only


def test_defaults_are_the_class_defaults():
    assert quick_constructor(VehicleState)() == VehicleState()
    assert quick_constructor(PilotAltitude)(t_mono=1.0) == PilotAltitude(t_mono=1.0)
    with pytest.raises(TypeError):
        quick_constructor(VehicleMessage)(1.0)  # required fields stay required
    with pytest.raises(TypeError):
        quick_constructor(Attitude)(roll=1.0)  # no such field


def test_quick_replace_is_dataclasses_replace():
    att = Attitude(t_mono=1.0, roll_rad=0.1, pitch_rad=0.2)
    new = quick_replace(att, roll_rad=0.5, yaw_rad=0.3)
    assert new == dataclasses.replace(att, roll_rad=0.5, yaw_rad=0.3)
    assert type(new) is Attitude and att.roll_rad == 0.1  # the original is untouched
    with pytest.raises(dataclasses.FrozenInstanceError):
        new.roll_rad = 0.0
    with pytest.raises(AttributeError):
        quick_replace(att, roll=0.5)


def test_a_frozen_draft_is_a_copy():
    draft = unfrozen_twin(VehicleState)()
    first = freeze_draft(draft, VehicleState)
    draft.attitude = Attitude(t_mono=2.0)
    second = freeze_draft(draft, VehicleState)
    assert first.attitude == Attitude() and second.attitude.t_mono == 2.0
    assert second.heartbeat is first.heartbeat  # groups are shared, not copied
