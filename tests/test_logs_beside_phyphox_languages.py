"""A phyphox export made on a phone in another language reads as the English one.

phyphox writes its tables' labels in the phone's language: a German phone's experiment exports
``"Zeit (s)","Beschleunigung x (m/s^2)",…``, a French one's ``"Temps (s)","Accélération x (m/s^2)",…``. The
reader knew only English words: such an export was "no time column" or "not a recognised log" (status 2).
The time column's and the sensors' words are now taken in the languages phyphox is translated to; the
samples are the English export's, bit for bit, and a linear (gravity-free) acceleration is still told
from the one with g in each language.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_phone_exports import motion, phyphox_csv

from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from protocol.errors import InputFormatError
from tests.log_support import assert_same_samples

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG

# language -> (time, acceleration, gyroscope, magnetic field, linear acceleration): the labels' words
WORDS = {
    "en": ("Time", "Acceleration", "Gyroscope", "Magnetic field", "Linear Acceleration"),
    "de": ("Zeit", "Beschleunigung", "Gyroskop", "Magnetfeld", "Lineare Beschleunigung"),
    "fr": ("Temps", "Accélération", "Gyroscope", "Champ magnétique", "Accélération linéaire"),
    "es": ("Tiempo", "Aceleración", "Giroscopio", "Campo magnético", "Aceleración lineal"),
    "it": ("Tempo", "Accelerazione", "Giroscopio", "Campo magnetico", "Accelerazione lineare"),
    "pt": ("Tempo", "Aceleração", "Giroscópio", "Campo magnético", "Aceleração linear"),
    "nl": ("Tijd", "Versnelling", "Gyroscoop", "Magnetisch veld", "Lineaire versnelling"),
    "pl": ("Czas", "Przyspieszenie", "Żyroskop", "Pole magnetyczne", "Przyspieszenie liniowe"),
}
UNITS = {ACC: "m/s^2", GYR: "rad/s", MAG: "µT"}


def _export(folder: Path, language: str, linear: bool, names: str) -> Path:
    """An experiment's export in ``language``: one table per sensor (and a linear acceleration's), its
    files named in English (``names="en"``) or after the sensor's word (``names="own"``)."""
    time, *sensors = WORDS[language]
    t, gyr, acc, mag = motion()
    tables = [(ACC, sensors[0], acc), (GYR, sensors[1], gyr), (MAG, sensors[2], mag)]
    if linear:
        tables.append((ACC, sensors[3], acc - [0.0, 0.0, 9.80665]))
    for i, (kind, word, xyz) in enumerate(tables):
        file = f"{WORDS['en'][1 + i]}.csv" if names == "en" else f"{word}.csv"
        columns = (f"{time} (s)", *(f"{word} {axis} ({UNITS[kind]})" for axis in "xyz"))
        phyphox_csv(folder / file, columns, t, xyz)
    return folder


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(language=st.sampled_from(sorted(WORDS)), linear=st.booleans(), names=st.sampled_from(["en", "own"]))
def test_an_export_in_any_of_phyphoxs_languages_reads_as_the_english_one(
    tmp_path_factory, language, linear, names
):
    reference = read_log(_export(tmp_path_factory.mktemp("en"), "en", False, "en"))
    log = read_log(_export(tmp_path_factory.mktemp(language), language, linear, names))
    assert log.format == "phyphox"
    assert_same_samples(log, reference)  # the linear acceleration ignored beside the one with g


@pytest.mark.parametrize("language", ["de", "fr", "es", "pl"])
def test_a_linear_acceleration_alone_is_refused_in_any_language(tmp_path, language):
    time, _, gyr_word, mag_word, linear_word = WORDS[language]
    t, gyr, acc, mag = motion()
    for word, kind, xyz in ((linear_word, ACC, acc), (gyr_word, GYR, gyr), (mag_word, MAG, mag)):
        columns = (f"{time} (s)", *(f"{word} {axis} ({UNITS[kind]})" for axis in "xyz"))
        phyphox_csv(tmp_path / f"{word}.csv", columns, t, xyz)
    with pytest.raises(InputFormatError, match="(?i)linear|gravity"):
        read_log(tmp_path)
