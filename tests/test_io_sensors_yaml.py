"""The calibrated YAML's emitter: libyaml's (where PyYAML has it) writes the text PyYAML's own does."""

import numpy as np
import pytest
import yaml

from pedcal.io import sensors_yaml
from pedcal.io.sensors_yaml import _CDumper, _Dumper, dump_yaml, flow_vector, read_sensors_yaml, sensors_yaml_text
from pedcal.model import SensorExtrinsics, SensorNetwork

needs_libyaml = pytest.mark.skipif(_CDumper is None, reason="PyYAML built without libyaml")


def _pyyaml_text(data) -> str:
    """dump_yaml's text with libyaml's emitter taken away: PyYAML's own, the reference."""
    with pytest.MonkeyPatch.context() as m:
        m.setattr(sensors_yaml, "_CDumper", None)
        return dump_yaml(data)


def _calibrated_network() -> SensorNetwork:
    rng = np.random.default_rng(3)
    sensors = []
    for i in range(4):
        s = SensorExtrinsics(f"{i + 1:02d}", rng.normal(size=3) + [0, 0, 2.6], rng.normal(scale=40, size=3),
                             observations=100 + i, status="ok" if i else "degenerate")
        s.sigma_position_m = np.abs(rng.normal(scale=0.02, size=3))
        s.sigma_ypr_deg = np.abs(rng.normal(scale=0.2, size=3))
        s.sigma_rotation_deg = np.abs(rng.normal(scale=0.2, size=3))
        if not i:
            s.unobservable = ["rotation about the robot's line of travel"]
        sensors.append(s)
    net = SensorNetwork(sensors, "map")
    cov = rng.normal(size=(12, 12))
    net.extra["tracker_latency_s"] = 0.0946
    net.extra["head_model"] = {"vertical_offset_m": -0.1041, "estimated": True, "height_reference": "none",
                               "note": "a note of 'quotes', 5\" (inches), colons: and # signs, μm and ± "
                                       "long enough to be folded over several lines by the emitter " * 2}
    net.extra["position_covariance_m2"] = {"sensors": [s.id for s in sensors], "order": "x y z per sensor",
                                           "matrix": [flow_vector(r) for r in cov @ cov.T * 1e-4]}
    net.extra["clock_offset_s"] = {s.id: np.float64(0.01 * i) for i, s in enumerate(sensors)}
    return net


@needs_libyaml
def test_calibrated_file_text_is_pyyaml_s(tmp_path, monkeypatch):
    net = _calibrated_network()
    with monkeypatch.context() as m:
        m.setattr(sensors_yaml, "_Dumper", _RefusedDumper)      # (libyaml's text, none of the guard's cases)
        text = sensors_yaml_text(net)
    assert "matrix:\n  - [" in text                   # (the flow rows, compared as written)
    with monkeypatch.context() as m:
        m.setattr(sensors_yaml, "_CDumper", None)
        assert sensors_yaml_text(net) == text
    # the same through the writer's own path, and it reads back
    (tmp_path / "out.yaml").write_text(text)
    back = read_sensors_yaml(tmp_path / "out.yaml")
    assert [s.id for s in back] == ["01", "02", "03", "04"]
    np.testing.assert_array_equal(back["03"].position_m, net["03"].position_m)


@needs_libyaml
@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf"), 1e-300, -0.0, 12345678901234567890,
                                   True, None, "", "yes", "null", "0.1", " lead", "trail ", "- item", "*x", "&x",
                                   "%x", "@x", "`x", "a\tb", "bell\x07", "a\u00a0b", "a\u2028b", "\ufeffx",
                                   "line one\nline two\n  indented\n", "漢字 μ ±"])
def test_scalars_written_alike(value):
    data = {"k": value, "list": [value, flow_vector([1.5, 2.0])], "nested": {"v": value}}
    assert dump_yaml(data) == _pyyaml_text(data)


@needs_libyaml
@pytest.mark.parametrize("char", ["\x85", "\U0001F600", "\U00010000", "\U0010FFFF"])
def test_characters_libyaml_escapes_written_by_pyyaml(char):
    """NEL and the characters beyond the Basic Multilingual Plane, which libyaml escapes where
    PyYAML may not: the text is PyYAML's."""
    data = {"frame": f"a{char}b", "sensors": []}
    assert dump_yaml(data) == _pyyaml_text(data)
    assert ("\U0001F600" in dump_yaml(data)) == (char == "\U0001F600")      # (written as it is, not escaped)


@needs_libyaml
def test_double_quoted_key_opening_a_flow_mapping_written_by_pyyaml():
    """A double-quoted scalar right after a flow mapping's brace (a mapping in a one-line list, here
    an object array among the extra keys): libyaml escapes it, the text is PyYAML's."""
    data = {"frame": "map", "extra": {"x": np.array([{"\U0001F600": 1}], dtype=object)}}
    assert dump_yaml(data) == _pyyaml_text(data) == "frame: map\nextra:\n  x: [{\U0001F600: 1}]\n"


@needs_libyaml
def test_backslash_escapes_spelt_out_in_a_plain_scalar_written_by_libyaml(monkeypatch):
    """A backslash and N or U in a plain scalar is no escape: written as it is, by libyaml."""
    data = {"frame": "map", "note": "\\N and \\U written as such", "sensors": [{"id": "a\\U0001F600"}]}
    assert dump_yaml(data) == _pyyaml_text(data)
    assert "note: \\N and \\U written as such\n" in dump_yaml(data)
    assert _written_by_libyaml(data, monkeypatch)


@needs_libyaml
def test_every_latin_and_greek_character_written_alike():
    for cp in range(0x20, 0x800):
        data = {"k": "a" + chr(cp) + "b"}
        assert dump_yaml(data) == _pyyaml_text(data), hex(cp)


def test_lone_surrogate_read_from_a_file_written_back_as_pyyaml_does(tmp_path, monkeypatch):
    """libyaml's emitter cannot encode a lone surrogate (a "\\uDCFF" escape read from a file) and
    raises; PyYAML's escapes it: the text is PyYAML's."""
    from pedcal.io.sensors_yaml import write_sensors_yaml

    (tmp_path / "in.yaml").write_text('frame: map\nsensors:\n- id: "s\\uDCFF"\n  position: [1.0, 2.0, 2.6]\n'
                                      '  ypr_deg: [0.0, 0.0, 90.0]\n')
    net = read_sensors_yaml(tmp_path / "in.yaml")
    assert [s.id for s in net] == ["s\udcff"]
    write_sensors_yaml(net, tmp_path / "out.yaml")
    monkeypatch.setattr(sensors_yaml, "_CDumper", None)
    assert (tmp_path / "out.yaml").read_text() == sensors_yaml_text(net)
    assert '- id: "s\\uDCFF"\n' in sensors_yaml_text(net)


class _PyYAMLEmitterUsed(Exception):
    pass


class _RefusedDumper(yaml.SafeDumper):
    def __init__(self, *args, **kwargs):
        raise _PyYAMLEmitterUsed


def _written_by_libyaml(data, monkeypatch) -> bool:
    """Whether dump_yaml writes ``data`` with libyaml's emitter alone (PyYAML's refused)."""
    with monkeypatch.context() as m:
        m.setattr(sensors_yaml, "_Dumper", _RefusedDumper)
        try:
            dump_yaml(data)
        except _PyYAMLEmitterUsed:
            return False
    return True


_TAME = list("abcXYZ019 .-_:#'") + ["é", "μ", "±", "漢字", "  ", "- ", ": ", " #", "yes", "null", "1e3", "~"]
_WILD = _TAME + list("?[]{},&*!|>%@`\"\\=") + ["\t", "\n", "\r", "\r\n", "\x00", "\x07", "\x1b", "\x7f", "\x85",
                 "\xa0", "\u2028", "\u2029", "\ufeff", "\U0001F600", "\U00010000", "\udcff", "0x1F"]


def _random_string(rng: np.random.Generator) -> str:
    """Short or long (past a key's 128 bytes), of the tame pieces alone half the time (libyaml's
    to write, mostly), else of any (tabs, control characters, line breaks, quotes, NEL, astral
    characters, a lone surrogate)."""
    pieces = _TAME if rng.random() < 0.5 else _WILD
    n = int(rng.integers(0, 12)) if rng.random() < 0.7 else int(rng.integers(40, 160))
    return "".join(pieces[i] for i in rng.integers(0, len(pieces), size=n))


@needs_libyaml
@pytest.mark.parametrize("seed", range(4))
def test_random_strings_as_values_and_keys_written_as_pyyaml_does(seed, monkeypatch):
    rng = np.random.default_rng(seed)
    by_libyaml = 0
    for _ in range(100):
        value, key = _random_string(rng), _random_string(rng)
        data = {"frame": value, "sensors": [{"id": value, "position": flow_vector([1.0, 2.0, 2.6]),
                                             "unobservable": flow_vector([]) if rng.random() < 0.5 else [value]}],
                key: {key: [value, key]}, "k": value}
        assert dump_yaml(data) == _pyyaml_text(data), (value, key)
        by_libyaml += _written_by_libyaml(data, monkeypatch)
    assert by_libyaml >= 10         # (the guard lets libyaml write the plain ones)


@needs_libyaml
def test_empty_key_written_as_pyyaml_does(monkeypatch):
    data = {"frame": "map", "extra": {"": 1.5, "b": {"": None}}}
    assert dump_yaml(data) == _pyyaml_text(data)
    assert not _written_by_libyaml(data, monkeypatch)


@needs_libyaml
@pytest.mark.parametrize("key", ["k" * 101, "k" * 123, "k" * 128, "μ" * 65, "漢" * 43, "a" * 300],
                         ids=lambda k: f"{len(k)}x{ord(k[0]):x}")
def test_long_key_written_as_pyyaml_does(key, monkeypatch):
    data = {"frame": "map", "sensors": [{key: 1, "id": "s01"}], "extra": {key: [1, 2]}}
    assert dump_yaml(data) == _pyyaml_text(data)
    assert not _written_by_libyaml(data, monkeypatch)
    in_array = {"frame": "map", "extra": {"x": np.array([{key: 1}], dtype=object)}}   # (an object array's dict)
    assert dump_yaml(in_array) == _pyyaml_text(in_array)
    assert not _written_by_libyaml(in_array, monkeypatch)
    short = {"frame": "map", "extra": {"k" * 100: 1, "μ" * 50: 2}}      # (100 bytes: libyaml's)
    assert dump_yaml(short) == _pyyaml_text(short) and _written_by_libyaml(short, monkeypatch)


def test_factor_graph_s_calibrated_file_written_by_libyaml(tmp_path, monkeypatch):
    """The guard leaves the factor graph's own output (covariance, head model, notes) to libyaml."""
    from pedcal.calib import calibrate
    from pedcal.io.sensors_yaml import write_sensors_yaml
    from pedcal.sim import simulate_logs

    if _CDumper is None:
        pytest.skip("PyYAML built without libyaml")
    with pytest.warns(Warning):
        network = calibrate(simulate_logs("paper", seed=0).calib, "factorgraph").network
    monkeypatch.setattr(sensors_yaml, "_Dumper", _RefusedDumper)
    write_sensors_yaml(network, tmp_path / "calibrated.yaml")
    text = (tmp_path / "calibrated.yaml").read_text()
    assert "position_covariance_m2" in text and "head_model" in text
    monkeypatch.setattr(sensors_yaml, "_Dumper", _Dumper)
    monkeypatch.setattr(sensors_yaml, "_CDumper", None)
    assert sensors_yaml_text(network) == text


@pytest.mark.parametrize("data", [
    {"frame": "map", "extra": {"s": {""}}},                         # an empty key inside a set
    {"frame": "map", "extra": {b"": 1}},                            # an empty bytes key
    {"frame": "map", "extra": {"x": np.array(["a", "a\x85b"])}},    # a quoted item after ", " in a flow row
    {"frame": "map", "unobservable": ["a\x85b"]},                   # a quoted item on a "- " line alone
])
def test_each_part_of_the_libyaml_guard_sends_its_case_to_pyyaml(data):
    # each input writes otherwise through libyaml; each is caught by one part of the guard alone
    assert dump_yaml(data) == _pyyaml_text(data)


def test_merge_keys_and_aliases_are_no_repeated_keys(tmp_path):
    """``<<: *base`` then a key of the base's: YAML's override, not a key given twice."""
    p = tmp_path / "sensors.yaml"
    p.write_text("base: &b {position: [0, 0, 2.6], ypr_deg: [0, 45, 0]}\n"
                 "sensors:\n- {<<: *b, id: a}\n- {<<: *b, id: b, position: [1, 0, 2.6]}\n- {<<: *b, id: c}\n")
    net = read_sensors_yaml(p)
    assert [s.id for s in net] == ["a", "b", "c"]
    np.testing.assert_array_equal(net["b"].position_m, [1, 0, 2.6])


def test_two_merge_keys_merge_both_as_pyyaml_does(tmp_path):
    """``{<<: *p, <<: *o}`` is read as PyYAML reads it, the merge of both, as ``<<: [*p, *o]`` is:
    a merge key is no key given twice. (Which one's value wins where both give a key is PyYAML's
    choice, not pinned here.)"""
    p = tmp_path / "sensors.yaml"
    anchors = "p: &p {position: [0, 0, 2.6]}\no: &o {ypr_deg: [0, 45, 0]}\n"
    p.write_text(anchors + "sensors:\n- {<<: *p, <<: *o, id: a}\n")
    net = read_sensors_yaml(p)
    np.testing.assert_array_equal(net["a"].position_m, [0, 0, 2.6])
    np.testing.assert_array_equal(net["a"].ypr_deg, [0, 45, 0])
    q = tmp_path / "list.yaml"
    q.write_text(anchors + "sensors:\n- {<<: [*p, *o], id: a}\n")
    assert read_sensors_yaml(q)["a"].to_dict() == net["a"].to_dict()


def test_meta_and_scenario_files_refuse_a_key_given_twice(tmp_path):
    from pedcal.errors import PedcalInputError
    from pedcal.io.logdir import read_meta
    from pedcal.sim.scenario import load_scenario

    meta = tmp_path / "meta.yaml"
    meta.write_text("head_offset: [0, 0, 1.35]\nhead_offset: [0, 0, 1.2]\n")
    with pytest.raises(PedcalInputError, match=r"key 'head_offset' appears twice .*line 1 and line 2"):
        read_meta(meta)
    scenario = tmp_path / "s.yaml"
    scenario.write_text("base: paper\nseed_note: 1\nbase: sparse\n")
    with pytest.raises(PedcalInputError, match=r"key 'base' appears twice .*line 1 and line 3"):
        load_scenario(scenario)


@pytest.mark.parametrize("value,shown", [("[abc, 45, 0]", "['abc', 45, 0]"), ("[.nan, 0.5, 1]", "[nan, 0.5, 1]"),
                                         ("[0, 45]", "[0, 45]"), ("7", "7"), ("[~, 45, 0]", "[None, 45, 0]"),
                                         ("[[1], 2, 3, 4, 5, 6, 7]", "[[1], 2, 3, 4, 5, 6, ...]"),
                                         ("[[[1]], x]", "[[[...]], 'x']")])
def test_a_bad_vector_is_quoted_item_by_item(tmp_path, value, shown):
    """A list was quoted as the text of its Python form, its strings' quotes escaped: '[\\'abc\\', ...]'."""
    from pedcal.errors import PedcalInputError

    p = tmp_path / "sensors.yaml"
    p.write_text(f"sensors:\n- id: a\n  position: [0, 0, 2.6]\n  ypr_deg: {value}\n")
    with pytest.raises(PedcalInputError) as ei:
        read_sensors_yaml(p)
    assert str(ei.value).endswith(f"ypr_deg: expected a list of 3 finite numbers, got {shown}")


@pytest.mark.parametrize("extra,message", [
    ("clock_offset_s: [0.1, 0.2]", "'clock_offset_s' must be a mapping of sensor id to seconds, got [0.1, 0.2]"),
    ("head_model: [a, 1]", "'head_model' must be a mapping of vertical_offset_m, ray_shift_m, horizontal_shift_m, "
                           "curvature_m, got ['a', 1]"),
    ("head_model: {per_sensor_shift_m: [0.01, x]}",
     "'head_model.per_sensor_shift_m' must be a mapping of sensor id to metres, got [0.01, 'x']"),
    ("head_model: {horizontal_profile: {distance_m: 1}}",
     "'head_model.horizontal_profile' must be a mapping with lists distance_m and shift_m, got {'distance_m': 1}"),
    ("head_model: {horizontal_profile: {distance_m: [2.0, 1.0], shift_m: [0, 0]}}",
     "'head_model.horizontal_profile.distance_m' must increase, got [2.0, 1.0]")])
def test_a_bad_calibration_key_quotes_its_value_item_by_item(tmp_path, extra, message):
    """A list or mapping in a message reads as YAML wrote it, not as the quoted text of its Python form."""
    from pedcal.errors import PedcalInputError

    p = tmp_path / "sensors.yaml"
    p.write_text(f"sensors:\n- id: a\n  position: [0, 0, 2.6]\n  ypr_deg: [0, 45, 0]\n{extra}\n")
    with pytest.raises(PedcalInputError) as ei:
        read_sensors_yaml(p)
    assert str(ei.value) == f"{p}: {message}"


def test_writing_a_network_with_a_nan_pose_quotes_the_pose(tmp_path):
    from pedcal.errors import PedcalInputError

    net = SensorNetwork([SensorExtrinsics("a", [0.0, np.nan, 2.6], [0.0, 45.0, 0.0])])
    with pytest.raises(PedcalInputError) as ei:
        sensors_yaml.write_sensors_yaml(net, tmp_path / "s.yaml")
    assert str(ei.value) == "network: sensor 'a' position [0.0, nan, 2.6]: expected finite values within +-1e+06 m"
