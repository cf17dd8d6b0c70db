"""Reading untrusted JSON (:func:`processing.common.files.parse_json`): every way a file can fail to be the
JSON it should be is one :class:`JSONFileError` line naming the file and the remedy, never a traceback."""

from __future__ import annotations

import pickle

import pytest

from processing.common.files import JSONFileError, parse_json
from processing.errors import InputError

#: Valid JSON whose arrays nest 100 000 deep: :func:`json.loads` alone raises ``RecursionError``.
DEEP = "[" * 100_000 + "]" * 100_000


@pytest.mark.parametrize("data", [DEEP, DEEP.encode(), ('{"a": ' + DEEP + "}").encode()])
def test_json_nested_100000_deep_is_one_line_naming_the_file(data):
    with pytest.raises(JSONFileError) as err:
        parse_json(data, "products/x.json", "write it again")
    assert str(err.value) == ("products/x.json is not JSON kogei can read (arrays or objects nested too deeply to "
                              "read); write it again")
    assert err.value.reason == "arrays or objects nested too deeply to read"
    assert isinstance(err.value, InputError) and isinstance(err.value, ValueError)


@pytest.mark.parametrize("data, reason", [
    (b"{not json", "Expecting property name enclosed in double quotes: line 1 column 2 (char 1)"),
    (b"", "Expecting value: line 1 column 1 (char 0)"),
    (b'{"a": "\xff"}', "not UTF-8 text: invalid start byte at byte 7"),
])
def test_malformed_or_non_utf8_json_is_one_line(data, reason):
    with pytest.raises(JSONFileError) as err:
        parse_json(data, "a.json", "restore it")
    assert err.value.reason == reason
    assert str(err.value) == f"a.json is not JSON kogei can read ({reason}); restore it"


def test_good_json_and_a_nesting_kogei_writes_are_read():
    assert parse_json(b'{"a": [1, 2.5, null, true, "x"]}', "a.json", "-") == {"a": [1, 2.5, None, True, "x"]}
    assert parse_json("[" * 50 + "]" * 50, "a.json", "-") is not None


def test_the_error_survives_pickling():
    # a batch worker's error crosses to the parent process
    with pytest.raises(JSONFileError) as err:
        parse_json(DEEP, "a.json", "write it again")
    back = pickle.loads(pickle.dumps(err.value))
    assert type(back) is JSONFileError and str(back) == str(err.value) and back.reason == err.value.reason
