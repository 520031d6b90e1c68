"""Plant families: reproducible draws, the drawn plants against python-control, bad specs."""

from __future__ import annotations

import json

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stcgym.envs.families import (
    FamilySpecError,
    draw_plant,
    draw_plants,
    load_family,
    plant_features,
)

RICH = {
    "name": "rich",
    "seed": 7,
    "count": 400,
    "order": 3,
    "poles": {
        "magnitude": [0.2, 0.9],
        "angle": [0.1, 0.6],
        "complex_share": 0.5,
        "unstable_share": 0.3,
        "unstable_magnitude": [1.05, 1.3],
    },
    "zeros": {
        "magnitude": [0.0, 0.8],
        "nonminimum_phase_share": 0.4,
        "nonminimum_phase_magnitude": [1.5, 2.5],
    },
    "dc_gain": [0.5, 8.0],
    "jump": {"at": 0.5, "magnitude_scale": [0.8, 1.1], "dc_gain_scale": [0.5, 2.0]},
}


def test_a_plant_depends_only_on_family_seed_and_index():
    fam = load_family(RICH)
    chunk = draw_plants(fam, range(100, 140))
    for p in chunk[::7]:
        alone = draw_plant(fam, p.index)
        np.testing.assert_array_equal(alone.a, p.a)
        np.testing.assert_array_equal(alone.b, p.b)
        np.testing.assert_array_equal(alone.a_after, p.a_after)
    other = draw_plant(load_family({**RICH, "seed": 8}), 100)
    assert not np.array_equal(other.a, chunk[0].a)
    # The count does not enter the draw: plant 5 of a bigger family is the same plant.
    np.testing.assert_array_equal(draw_plant(load_family({**RICH, "count": 1000}), 5).b,
                                  draw_plant(fam, 5).b)  # fmt: skip


def test_yaml_and_json_files_give_the_same_family(tmp_path):
    yaml = pytest.importorskip("yaml")
    (tmp_path / "f.yaml").write_text(yaml.safe_dump(RICH))
    (tmp_path / "f.json").write_text(json.dumps(RICH))
    a, b = load_family(tmp_path / "f.yaml"), load_family(tmp_path / "f.json")
    assert a.to_dict() == b.to_dict() == load_family(RICH).to_dict()
    # A validated spec validates again unchanged (what a resumed sweep reads back).
    assert load_family(a.to_dict()).to_dict() == a.to_dict()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), index=st.integers(0, 399), order=st.integers(1, 5))
def test_drawn_coefficients_have_the_drawn_poles_zeros_and_gain(seed, index, order):
    fam = load_family({**RICH, "seed": seed, "order": order})
    p = draw_plant(fam, index)
    sys = control.tf(p.b, np.concatenate(([1.0], p.a)), dt=1)
    np.testing.assert_allclose(np.sort_complex(sys.poles()), np.sort_complex(p.poles), atol=1e-7)
    if order > 1:
        np.testing.assert_allclose(
            np.sort_complex(sys.zeros()), np.sort_complex(p.zeros.astype(complex)), atol=1e-7
        )
    np.testing.assert_allclose(float(np.real(sys.dcgain())), p.dc_gain, rtol=1e-8)
    lo, hi = RICH["dc_gain"]
    assert lo <= p.dc_gain <= hi
    after = control.tf(p.b_after, np.concatenate(([1.0], p.a_after)), dt=1)
    np.testing.assert_allclose(
        np.sort_complex(after.poles()), np.sort_complex(p.poles_after), atol=1e-7
    )
    np.testing.assert_allclose(float(np.real(after.dcgain())), p.dc_gain_after, rtol=1e-8)
    assert 0.5 - 1e-12 <= p.dc_gain_after / p.dc_gain <= 2.0 + 1e-12
    f = plant_features(p)
    assert f["pole_mag_max"] == pytest.approx(np.abs(sys.poles()).max())
    assert f["unstable"] == float(np.abs(sys.poles()).max() > 1)


def test_shares_and_ranges_are_respected():
    plants = draw_plants(load_family(RICH), range(400))
    unstable = np.array([np.abs(p.poles).max() > 1 for p in plants])
    nmp = np.array([np.abs(p.zeros).max() > 1 for p in plants])
    # Binomial(400, 0.3) and (400, 0.4): 5 standard deviations are about 0.11 and 0.12.
    assert abs(unstable.mean() - 0.3) < 0.11 and abs(nmp.mean() - 0.4) < 0.12
    for p in plants:
        mags = np.sort(np.abs(p.poles))
        stable = mags[mags < 1]
        assert np.all((stable >= 0.2 - 1e-12) & (stable <= 0.9 + 1e-12))
        assert np.sum(mags > 1) <= 1 and np.all((mags[mags > 1] >= 1.05) & (mags[mags > 1] <= 1.3))
        zmag = np.abs(p.zeros)
        assert np.sum(zmag > 1) <= 1
        assert np.all((zmag[zmag > 1] >= 1.5) & (zmag[zmag > 1] <= 2.5))


def test_shares_at_the_extremes():
    base = {"count": 50, "order": 4}
    real = draw_plants(load_family({**base, "poles": {"complex_share": 0.0}}), range(50))
    assert all(np.all(p.poles.imag == 0) for p in real)
    cplx = draw_plants(load_family({**base, "poles": {"complex_share": 1.0}}), range(50))
    assert all(np.all(p.poles.imag != 0) for p in cplx)
    unst = draw_plants(
        load_family({**base, "poles": {"complex_share": 1.0, "unstable_share": 1.0}}), range(50)
    )
    assert all(np.sum(np.abs(p.poles) > 1) == 1 for p in unst)
    first = load_family({"count": 5, "order": 1})
    assert all(p.zeros.size == 0 and p.b.size == 1 for p in draw_plants(first, range(5)))


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"colour": "red"}, r"unknown key\(s\) \['colour'\]"),
        ({"poles": {"magnitude": [0.1, 0.5], "radius": 1}}, r"poles\.radius"),
        ({"count": -3}, "count must be an integer >= 1"),
        ({"count": 0}, "count must be an integer >= 1"),
        ({"count": 2.5}, "count must be an integer"),
        ({"poles": {"magnitude": [0.9, 0.5]}}, r"poles\.magnitude .*low <= high"),
        ({"poles": {"magnitude": [0.5, 1.2]}}, r"poles\.magnitude .*stable radii"),
        ({"poles": {"magnitude": [-0.5, 0.5]}}, r"poles\.magnitude"),
        ({"poles": {"unstable_magnitude": [0.9, 1.2]}}, r"poles\.unstable_magnitude"),
        ({"poles": {"angle": [0.2, 1.5]}}, r"poles\.angle"),
        ({"poles": {"unstable_share": 1.5}}, r"poles\.unstable_share"),
        ({"zeros": {"magnitude": [0.5, 1.0]}}, r"zeros\.magnitude"),
        ({"zeros": {"nonminimum_phase_magnitude": [0.5, 2]}}, "nonminimum_phase_magnitude"),
        ({"dc_gain": [-1.0, 2.0]}, "dc_gain"),
        ({"order": 0}, "order"),
        ({"noise_std": -0.1}, "noise_std"),
        ({"reference": {"kind": "prbs"}}, r"reference\.kind"),
        ({"jump": {"at": 1.5e3}}, r"jump\.at"),
        ({"jump": {"when": 3}}, r"jump\.when"),
        ({"drift": {"std": -1}}, r"drift\.std"),
        ({"drift": {"std": 0.1}, "jump": {"at": 0.5}}, "jump or drift"),
    ],
)
def test_bad_specs_are_clear_errors(change, match):
    with pytest.raises(FamilySpecError, match=match):
        load_family({"count": 10, "steps": 1000, **change})


def test_count_is_required_and_files_are_checked(tmp_path):
    with pytest.raises(FamilySpecError, match="count"):
        load_family({"order": 2})
    with pytest.raises(FileNotFoundError):
        load_family(tmp_path / "missing.yaml")
    (tmp_path / "bad.json").write_text("{count: 3")
    with pytest.raises(FamilySpecError, match="not valid JSON"):
        load_family(tmp_path / "bad.json")
    with pytest.raises(ValueError, match="index"):
        draw_plant(load_family({"count": 3}), 3)
