"""Plant families: reproducible draws, the drawn plants against python-control, bad specs."""

from __future__ import annotations

import json
import zlib

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stcgym.envs.families import (
    FAMILIES,
    FamilySpecError,
    draw_plant,
    draw_plants,
    get_family,
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


def assert_drawn_alone(plants, family):
    """Each of ``plants`` is the plant of its index drawn alone from ``family``, before and
    after the jump."""
    for p in plants:
        alone = draw_plant(family, p.index)
        for key in ("a", "b", "a_after", "b_after"):
            np.testing.assert_array_equal(getattr(alone, key), getattr(p, key))


def test_a_plant_depends_only_on_family_seed_and_index():
    fam = load_family(RICH)
    chunk = draw_plants(fam, range(100, 140))
    assert_drawn_alone(chunk[::7], fam)
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


# --------------------------------------------------------------------------------------------
# Gain sign, initial state, random jumps, splits, variants, the registry
# --------------------------------------------------------------------------------------------
SISO2 = get_family("siso2-v1")


def _all_plants(family):
    """Every plant of the family's splits and variants, by split name."""
    out = {}
    for name in family.split_names:
        source, indices = family.members(name)
        out[name] = draw_plants(source, indices)
    return out


def test_the_sign_flip_is_drawn_last_from_the_plant_stream():
    """A flipped plant is the unflipped one with b (and b after the jump) negated: the flip
    changes nothing else that is drawn, so families without flips keep their plants."""
    never, always = (load_family({**RICH, "negative_gain_share": s}) for s in (0.0, 1.0))
    for i in range(0, 400, 37):
        p, q = draw_plant(never, i), draw_plant(always, i)
        np.testing.assert_array_equal(q.a, p.a)
        np.testing.assert_array_equal(q.b, -p.b)
        np.testing.assert_array_equal(q.a_after, p.a_after)
        np.testing.assert_array_equal(q.b_after, -p.b_after)
        assert q.dc_gain == -p.dc_gain and q.dc_gain_after == -p.dc_gain_after
        np.testing.assert_array_equal(q.zeros, p.zeros)


def test_the_default_family_against_python_control():
    """Poles, zeros and DC gain of every plant of siso2-v1 (1300) from python-control, and the
    shares of unstable, nonminimum-phase and negative-gain plants within binomial tolerance."""
    plants = draw_plants(SISO2, range(SISO2.count))
    unstable, nmp, negative = [], [], []
    for p in plants:
        sys = control.tf(p.b, np.concatenate(([1.0], p.a)), dt=1)
        poles, zeros = sys.poles(), sys.zeros()
        np.testing.assert_allclose(np.sort_complex(poles), np.sort_complex(p.poles), atol=1e-7)
        np.testing.assert_allclose(zeros, p.zeros, atol=1e-7)
        gain = float(np.real(sys.dcgain()))
        np.testing.assert_allclose(gain, p.dc_gain, rtol=1e-8)
        assert 0.5 - 1e-9 <= abs(gain) <= 5.0 + 1e-9
        unstable.append(np.abs(poles).max() > 1)
        nmp.append(np.abs(zeros).max() > 1)
        negative.append(gain < 0)
    n = len(plants)
    for share, expected in ((unstable, 0.25), (nmp, 0.25), (negative, 0.5)):
        sd = np.sqrt(expected * (1 - expected) / n)
        assert abs(np.mean(share) - expected) < 5 * sd, (np.mean(share), expected)


def test_every_plant_of_the_default_family_is_well_defined():
    """What the FAMILIES comment states: every coefficient finite, no b all zero, before and
    after the jump, over the splits and the variants (2300 plants)."""
    groups = _all_plants(SISO2)
    assert sum(len(g) for g in groups.values()) == 2300
    smallest_b = np.inf
    for plants in groups.values():
        for p in plants:
            coefficients = np.concatenate((p.a, p.b, p.a_after, p.b_after))
            assert np.all(np.isfinite(coefficients))
            smallest_b = min(smallest_b, np.abs(p.b).max(), np.abs(p.b_after).max())
    assert smallest_b > 1e-5


def test_the_variants_of_the_default_family_do_what_they_say():
    groups = _all_plants(SISO2)
    assert all(len(groups[v]) == 200 for v in SISO2.variant_names)
    assert all(1.15 <= np.abs(p.poles).max() <= 1.3 for p in groups["ood_fast_unstable"])
    assert all(1.05 <= np.abs(p.zeros).max() <= 1.3 for p in groups["ood_near_zero"])
    damped = groups["ood_lightly_damped"]
    assert all(np.all((np.abs(p.poles) >= 0.95) & (np.abs(p.poles) <= 0.99)) for p in damped)
    assert all(np.all(p.poles.imag != 0) for p in damped)
    assert all(5.0 - 1e-9 <= abs(p.dc_gain) <= 20.0 + 1e-9 for p in groups["ood_high_gain"])
    assert all(p.a.size == 3 and p.b.size == 3 for p in groups["ood_order3"])
    assert all(p.a.size == 2 for p in groups["train"])


def test_splits_are_disjoint_and_a_plant_is_the_same_in_any_split_or_chunk():
    spans = [SISO2.split_indices(s) for s in ("train", "validation", "test")]
    assert [(r.start, r.stop) for r in spans] == [(0, 1000), (1000, 1100), (1100, 1300)]
    assert set().union(*map(set, spans)) == set(range(1300))
    assert sum(len(r) for r in spans) == 1300
    # The split layout does not enter the draw: plant 1050 is the same under any splits.
    other = load_family({**SISO2.to_dict(), "splits": {"x": [1040, 1060]}, "variants": {}})
    chunk = draw_plants(SISO2, range(1040, 1060))
    assert_drawn_alone(chunk[::5], other)
    # A variant's plants are its own: another seed, documented.
    variant = SISO2.variant("ood_high_gain")
    assert variant["seed"] == 2026 * 2**32 + zlib.crc32(b"ood_high_gain")
    assert variant["name"] == "siso2.ood_high_gain" and variant.split_names == ["all"]
    assert variant.split_indices("all") == range(200)
    assert SISO2.members("ood_high_gain")[1] == range(200)


def test_a_variant_is_deep_merged_over_its_base():
    base = {
        "name": "b",
        "seed": 3,
        "count": 50,
        "poles": {"unstable_share": 0.5, "magnitude": [0.2, 0.4]},
        "reference": {"kind": "random_steps", "hold": [5, 9]},
        "jump": {"at": [0.2, 0.4], "probability": 0.3},
        "splits": {"train": [0, 40], "test": [40, 50]},
        "variants": {
            "v": {"count": 7, "poles": {"unstable_share": 1.0}, "jump": {"probability": 1.0}},
            "square": {"count": 3, "seed": 9, "reference": {"kind": "square", "period": 20}},
        },
    }
    spec = load_family(base)
    v = spec.variant("v")
    assert v["poles"]["unstable_share"] == 1.0 and v["poles"]["magnitude"] == [0.2, 0.4]
    assert v["jump"]["probability"] == 1.0 and v["jump"]["at"] == [0.2, 0.4]
    assert v["reference"]["hold"] == [5, 9] and v.count == 7 and v["splits"] == {"all": [0, 7]}
    square = spec.variant("square")  # the reference is replaced whole, not merged
    assert square["reference"] == {"kind": "square", "period": 20} and square["seed"] == 9
    assert spec.split_names == ["train", "test", "v", "square"]
    # The spec (variants included) validates again unchanged.
    assert load_family(spec.to_dict()).to_dict() == spec.to_dict()
    with pytest.raises(ValueError, match=r"split must be one of \['train', 'test', 'v', 'squa"):
        spec.members("validation")
    with pytest.raises(ValueError, match="no variant 'train'"):
        spec.variant("train")


def test_random_jumps_in_the_spec():
    spec = load_family({"count": 5, "steps": 200, "jump": {"at": [0.25, 0.5], "probability": 0.4}})
    assert spec.jump_range() == (50, 100) and spec.jump_range(400) == (100, 200)
    assert spec.jump_probability == 0.4
    with pytest.raises(ValueError, match="random jump"):
        _ = spec.jump_step
    steps = load_family({"count": 5, "steps": 200, "jump": {"at": [20, 120]}})
    assert steps.jump_range() == (20, 120) and steps.jump_range(400) == (20, 120)
    with pytest.raises(FamilySpecError, match=r"jump\.at"):
        steps.jump_range(100)  # step 120 lies past an episode of 100 steps
    fixed = load_family({"count": 5, "jump": {"at": 0.5}})
    assert fixed.jump_step == 500 and fixed.jump_probability == 1.0
    assert load_family({"count": 5}).jump_step is None
    assert load_family({"count": 5}).jump_probability == 0.0


def test_the_registry_and_get_family(tmp_path):
    yaml = pytest.importorskip("yaml")
    assert get_family(SISO2) is SISO2
    assert get_family(FAMILIES["siso2-v1"]).to_dict() == SISO2.to_dict()
    assert SISO2.key == "siso2-v1" and SISO2.version == 1 and SISO2["seed"] == 2026
    (tmp_path / "f.yaml").write_text(yaml.safe_dump(FAMILIES["siso2-v1"]))
    (tmp_path / "f.json").write_text(json.dumps(FAMILIES["siso2-v1"]))
    assert get_family(tmp_path / "f.yaml").to_dict() == SISO2.to_dict()
    assert get_family(str(tmp_path / "f.json")).to_dict() == SISO2.to_dict()
    with pytest.raises(ValueError, match=r"registered name \(one of \[.*'siso2-v1'"):
        get_family("siso3-v1")
    with pytest.raises(FileNotFoundError):
        get_family(tmp_path / "missing.yaml")
    with pytest.raises(TypeError, match="family must be"):
        get_family(3)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"version": 0}, "version must be an integer >= 1"),
        ({"negative_gain_share": 1.5}, "negative_gain_share"),
        ({"initial_state_std": -0.1}, "initial_state_std"),
        ({"jump": {"at": [0.6, 0.3]}}, r"jump\.at .*low <= high"),
        ({"jump": {"at": [0.3, 700]}}, r"jump\.at .*two fractions below 1 or of two steps"),
        ({"jump": {"at": [0.0, 0.5]}}, r"jump\.at"),
        ({"jump": {"at": [0.2, 0.4, 0.6]}}, r"jump\.at"),
        ({"jump": {"at": [100.5, 200]}}, r"jump\.at"),
        ({"jump": {"probability": -0.1}}, r"jump\.probability"),
        ({"splits": {"train": [0, 8], "test": [5, 10]}}, "splits.train .* overlap"),
        ({"splits": {"train": [0, 11]}}, r"splits\.train .*stop <= count = 10"),
        ({"splits": {"train": [4, 4]}}, r"splits\.train"),
        ({"splits": {"a/b": [0, 4]}}, "a split name"),
        ({"splits": {}}, "splits"),
        ({"variants": {"v": {"order": 3}}}, r"variants\.v .*own count"),
        ({"variants": {"all": {"count": 3}}}, r"variants\.all has the name of a split"),
        ({"variants": {"v": {"count": 3, "variants": {}}}}, r"variants\.v\.variants"),
        ({"variants": {"v": {"count": 3, "poles": {"radius": 1}}}}, r"variants\.v: .*poles\.rad"),
        ({"variants": {"v": {"count": 0}}}, r"variants\.v: count must be an integer >= 1"),
        ({"reference": {"kind": "random_steps", "hold": [9, 3]}}, "hold"),
    ],
)
def test_bad_new_keys_are_clear_errors(change, match):
    with pytest.raises(FamilySpecError, match=match):
        load_family({"count": 10, "steps": 1000, **change})
