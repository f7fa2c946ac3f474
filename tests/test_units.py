"""Units through pint: conversions against hand values, dimension checks, CSV suffixes."""

import numpy as np
import pytest

import mrjax.data as md
from mrjax._errors import InputError
from mrjax.data._units import check_unit, command_unit  # the loaders' unit check


def _raises(fn, *needles):
    with pytest.raises(InputError) as info:
        fn()
    msg = str(info.value)
    assert "\n" not in msg
    for n in needles:
        assert n in msg, f"{n!r} not in {msg!r}"
    return msg


# Hand values: exact definitions of the units (NIST SP 811).
HAND = [
    ("cm", "length", 0.01),
    ("in", "length", 0.0254),
    ("inch", "length", 0.0254),
    ("ft", "length", 0.3048),
    ("um", "length", 1e-6),
    ("ms", "time", 1e-3),
    ("min", "time", 60.0),
    ("mm/s", "velocity", 1e-3),
    ("cm/s", "velocity", 0.01),
    ("in/s", "velocity", 0.0254),
    ("m/min", "velocity", 1.0 / 60.0),
    ("kN", "force", 1e3),
    ("lbf", "force", 4.4482216152605),
    ("kgf", "force", 9.80665),
    ("mA", "current", 1e-3),
    ("mV", "voltage", 1e-3),
    ("kHz", "frequency", 1e3),
]


@pytest.mark.parametrize("unit, quantity, factor", HAND)
def test_hand_values(unit, quantity, factor):
    assert md.unit_scale(unit, quantity=quantity) == pytest.approx(factor, rel=1e-14)
    assert check_unit(unit, quantity, what="x") == pytest.approx(factor, rel=1e-14)
    assert md.to_si(3.0, unit, quantity=quantity) == pytest.approx(3.0 * factor, rel=1e-14)


def test_examples_of_the_brief():
    assert md.to_si(2.54, "cm") == pytest.approx(0.0254, rel=1e-15)
    assert md.to_si(1.0, "lbf") == pytest.approx(4.4482216152605, rel=1e-15)
    np.testing.assert_allclose(md.to_si([1.0, 2.0], "in/s"), [0.0254, 0.0508], rtol=1e-15)
    # Underscore spelling of a CSV suffix.
    assert md.to_si(10.0, "in_s", quantity="velocity") == pytest.approx(0.254, rel=1e-15)
    assert md.UNITS["length"]["in"] == pytest.approx(0.0254)
    assert md.UNITS["force"]["lbf"] == pytest.approx(4.4482216152605)
    assert set(md.UNITS) >= {"time", "length", "velocity", "force", "current", "voltage"}


def test_quantity_strings():
    assert md.quantity_value("500 mA", "current", what="current") == pytest.approx(0.5)
    assert md.quantity_value("500mA", "current", what="current") == pytest.approx(0.5)
    assert md.quantity_value("1 kHz", "frequency", what="rate") == pytest.approx(1000.0)
    assert md.quantity_value("8 mm", "length", what="amplitude") == pytest.approx(0.008)
    assert md.quantity_value("0.5", "current", what="current") == 0.5
    assert md.quantity_value(2, "current", what="current") == 2.0
    _raises(lambda: md.quantity_value("5 N", "current", what="current", where="--current"),
            "--current", "current unit 'N' is not a current", "force")
    _raises(lambda: md.quantity_value("lots", "current", what="current"), "current", "'lots'")
    _raises(lambda: md.quantity_value(True, "current", what="current"), "current")


@pytest.mark.parametrize(
    "unit, quantity, needle",
    [
        ("N", "length", "displacement unit 'N' is not a length (it is a force unit)"),
        ("mm", "force", "displacement unit 'mm' is not a force (it is a length unit)"),
        ("mm", "velocity", "is not a velocity"),
        ("V", "current", "is not a current (it is a voltage unit)"),
        ("N", "command", "is not a current or a voltage"),
        ("furlongz", "length", "unknown unit 'furlongz' for displacement; a length unit is"),
        ("", "length", "unknown unit '' for displacement"),
        ("mm)", "length", "unknown unit 'mm)'"),
    ],
)
def test_wrong_dimension_is_one_clear_line(unit, quantity, needle):
    _raises(lambda: check_unit(unit, quantity, what="displacement", where="f.csv"),
            "f.csv: ", needle)


def test_command_units_keep_their_kind():
    assert check_unit("V", "command", what="command") == 1.0
    assert check_unit("mA", "command", what="command") == pytest.approx(1e-3)
    assert command_unit("mV") == "V" and command_unit("mA") == "A" and command_unit("A") == "A"


def test_column_suffixes():
    assert md.parse_column("displacement_cm") == ("displacement", "cm")
    assert md.parse_column("force_lbf") == ("force", "lbf")
    assert md.parse_column("velocity_in_s") == ("velocity", "in/s")
    assert md.parse_column("command_V") == ("command", "V")
    assert md.parse_column("amplitude_in") == ("amplitude", "in")
    for name in ("displacement_cm", "velocity_in_s", "force_lbf", "command_V"):
        assert name in md.column_names()
    _raises(lambda: md.parse_column("force_mm", where="f.csv"), "f.csv", "'force_mm'",
            "not a force")
    _raises(lambda: md.parse_column("command_N"), "'command_N'", "not a current or a voltage")
