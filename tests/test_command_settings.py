"""The commands' options become settings in pure functions, tested apart from the work:
no dataset is read and nothing is written."""

from __future__ import annotations

import pytest

from experiments.command.options import UsageError
from experiments.fit.command import build_parser as fit_parser
from experiments.fit.command import fit_settings
from experiments.problem.fitting import ENERGY_NAMES


def _fit(*options: str):
    return fit_settings(fit_parser().parse_args(["data.npz", "--out", "out", *options]))


def test_the_default_fit_leaves_the_model_to_step_0():
    energy, settings = _fit()
    assert energy == "auto"
    assert settings.grid is None and settings.margin == 0.0
    assert settings.objective == "markers"


def test_the_papers_method_implies_its_energy_and_objective():
    for options in (("--method", "paper"), ("--objective", "control_points")):
        energy, settings = _fit(*options)
        assert energy == "dnurbs" and settings.energy == "dnurbs"
        assert settings.objective == "control_points"
        assert settings.names == tuple(ENERGY_NAMES["dnurbs"])


def test_a_chosen_energy_takes_its_model_options():
    energy, settings = _fit(
        "--energy", "linear-elastic", "--grid", "9x9x2", "--degrees", "2x2x1", "--margin", "5"
    )
    assert energy == "linear-elastic"
    assert settings.grid == (9, 9, 2) and settings.degrees == (2, 2, 1)
    assert settings.margin == 5.0 and settings.names == tuple(ENERGY_NAMES["linear-elastic"])


@pytest.mark.parametrize(
    "options, named",
    [
        (("--grid", "9x9x2"), "--grid"),
        (("--margin", "5"), "--margin"),
        (("--params", "E,nu"), "--params"),
        (("--energy", "linear-elastic", "--params", "alpha_u"), "alpha_u"),
        (("--method", "paper", "--margin", "5"), "--margin"),
    ],
)
def test_contradicting_options_are_refused_naming_the_option(options, named):
    with pytest.raises(UsageError, match=named):
        _fit(*options)


def _image(*options: str):
    from experiments.imaging.command import build_parser, image_settings

    return image_settings(build_parser().parse_args(["data.npz", "--out", "out", *options]))


def test_the_default_image_leaves_the_model_to_step_0_and_the_noise_to_the_data():
    settings, noise = _image()
    assert noise is None
    assert settings.fit.grid is None and settings.fit.margin == 0.0
    assert settings.fit.names == ("E", "nu") and settings.over == "surface"


def test_an_image_on_a_chosen_model_takes_its_options():
    settings, noise = _image(
        "--energy", "linear-elastic", "--grid", "9x9x2", "--field", "6x4", "--noise", "0.02"
    )
    assert settings.fit.grid == (9, 9, 2) and tuple(settings.shape) == (6, 4)
    assert noise == 0.02


@pytest.mark.parametrize(
    "options, named",
    [
        (("--grid", "9x9x2"), "--grid"),
        (("--field", "6x4x3"), "--field"),
        (("--noise", "0"), "--noise"),
        (("--weight", "sometimes"), "--weight"),
    ],
)
def test_bad_imaging_options_are_refused_naming_the_option(options, named):
    with pytest.raises(UsageError, match=named):
        _image(*options)
