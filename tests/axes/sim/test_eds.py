"""configs/eds: generated, up to date, loadable by python-canopen, with the EPOS2 facts right."""

from __future__ import annotations

import canopen
import pytest

from pvtflow.axes.drive import objects as od
from pvtflow.axes.sim.drive import EDS_DIR
from pvtflow.axes.sim.edsgen import DRIVES, render


@pytest.mark.parametrize("filename", sorted(DRIVES))
def test_eds_file_is_up_to_date_and_loads(filename: str) -> None:
    path = EDS_DIR / filename
    assert path.read_text(encoding="ascii") == render(filename), "run python -m pvtflow.axes.sim.edsgen"
    dictionary = canopen.import_od(str(path), 5)
    assert dictionary[0x1400][1].default == 0x205 and dictionary[0x1800][1].default == 0x80000185
    for index in (od.CONTROLWORD, od.STATUSWORD, od.POSITION_ACTUAL_VALUE):
        assert dictionary[index].pdo_mappable


def test_epos2_objects_match_the_real_drive() -> None:
    ours = canopen.import_od(str(EDS_DIR / "epos2.eds"), 1)
    record = ours[od.EPOS2_INTERPOLATION_DATA_RECORD]
    assert record.data_type == canopen.objectdictionary.UNSIGNED64
    assert record.access_type == "wo" and record.pdo_mappable
    assert not ours[od.INTERPOLATION_DATA_CONFIGURATION][2].pdo_mappable
    assert ours[od.EPOS2_INTERPOLATION_BUFFER][1].pdo_mappable
    assert ours[od.EPOS2_INTERPOLATION_BUFFER][2].default == 4
    assert ours[od.EPOS2_INTERPOLATION_BUFFER][3].default == 60
