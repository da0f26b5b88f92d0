"""SensorNetwork's look-up by id (pedcal.model): an index kept beside the list, right after the
list changes under it."""

import pytest

from pedcal.model import SensorExtrinsics, SensorNetwork


def _sensor(sid: str, x: float) -> SensorExtrinsics:
    return SensorExtrinsics(sid, [x, 0.0, 3.0], [0.0, 90.0, 0.0])


def test_look_up_by_id_follows_the_list_when_it_changes():
    net = SensorNetwork([_sensor("a", 1.0), _sensor("b", 2.0), _sensor("c", 3.0)])
    assert net["b"].position_m[0] == 2.0 and "c" in net and "d" not in net
    net.sensors[1] = _sensor("d", 4.0)              # replaced in place: b gone, d found
    assert "b" not in net and net["d"].position_m[0] == 4.0
    with pytest.raises(KeyError):
        net["b"]
    del net.sensors[0]                               # removed: the others' positions shift
    assert net["c"].position_m[0] == 3.0 and net["d"].position_m[0] == 4.0 and "a" not in net
    net.sensors.append(_sensor("e", 5.0))
    assert net["e"].position_m[0] == 5.0
    net.sensors.append(_sensor("7", 6.0))
    assert net[7].position_m[0] == 6.0 and 7 in net      # (ids are strings: a number is looked up as one)
