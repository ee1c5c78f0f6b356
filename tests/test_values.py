import pytest

from ecatcfg.esi.values import parse_bool, parse_hex_bytes, parse_int


@pytest.mark.parametrize("text,value", [
    ("#x1A00", 0x1A00), ("#x1a00", 0x1A00), ("0x1A00", 0x1A00), ("0X1a00", 0x1A00),
    ("6656", 6656), ("  42\n", 42), ("-500", -500), ("+7", 7), ("#X10", 16), ("007", 7),
])
def test_numbers_in_every_vendor_form(text, value):
    assert parse_int(text) == value


@pytest.mark.parametrize("text", ["", "#x", "0x", "x10", "1A00", "#x1G", "1_000", "#x1_0",
                                  "0x-1", "١٢", "1.5", "#x 10 20"])
def test_bad_numbers_are_refused_with_the_text(text):
    with pytest.raises(ValueError, match="not a number"):
        parse_int(text)


@pytest.mark.parametrize("text,value", [("1", True), ("0", False), ("true", True),
                                        ("false", False), (" TRUE ", True), ("False", False)])
def test_booleans(text, value):
    assert parse_bool(text) is value


@pytest.mark.parametrize("text", ["yes", "2", "", "t"])
def test_bad_booleans(text):
    with pytest.raises(ValueError, match="not a boolean"):
        parse_bool(text)


def test_hex_binary():
    assert parse_hex_bytes("0010f400 f410f400") == bytes.fromhex("0010f400f410f400")
    with pytest.raises(ValueError, match="odd number of digits"):
        parse_hex_bytes("2")
    with pytest.raises(ValueError, match="not hex bytes"):
        parse_hex_bytes("zz")
