"""One idea of a design: both scene families satisfy the Family protocol, a Design round-trips row -> vector
-> scene, and a newcomer's family, written here and nowhere in the library, samples, splits, maps to scenes
and generates through the public generator."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fixtures.helpers import fake_scene_solve as _fake_solve
from pcmgn_jax.data.dataset import FAMILIES, ensure_dataset, load_manifest
from pcmgn_jax.data.designs import SceneFamily, explicit_split, sampled_splits
from pcmgn_jax.data.family import Design, Family
from pcmgn_jax.data.layout import DatasetError
from pcmgn_jax.data.splits import load_splits, split_designs
from pcmgn_jax.data.stack import StackFamily, stack_layer_count
from pcmgn_jax.scene import default_scene, with_parameters


@dataclasses.dataclass(frozen=True)
class ImpactorFamily:
    """A newcomer's family: the ball's radius [m] and the cover glass's thickness [m], drawn uniformly."""

    name: str = "impactor"
    n_frames: int = 3
    padded = False
    plans = ()
    parameters = (("ball.radius", 3e-3, 6e-3), ("CG", 80e-6, 120e-6))
    units = ("m", "m")

    @property
    def names(self):
        return tuple(p[0] for p in self.parameters)

    def base(self, scene):
        return dataclasses.replace(scene, n_frames=self.n_frames, design_layers=("CG",))

    def scene(self, base, params):
        return with_parameters(base, params)

    def sample(self, n, seed):
        lo, hi = (np.array([p[i] for p in self.parameters]) for i in (1, 2))
        return lo + (hi - lo) * np.random.default_rng(seed).random((n, len(lo)))

    def sample_splits(self, n_train, n_test, seed, plan=None):
        return self.sample(n_train, seed), self.sample(n_test, seed + 1)

    def split_origin(self, seed, n_total, plan=None):
        return {"kind": "impactor", "seed": seed, "n_total": n_total}

    def canonical(self, params):
        return dict(params)



@pytest.mark.parametrize("name", sorted(FAMILIES))
def test_every_family_satisfies_the_protocol_and_round_trips(name):
    fam = FAMILIES[name]
    assert isinstance(fam, Family) and fam.name == name
    assert len(fam.names) == len(fam.parameters) == len(fam.units) and fam.names == tuple(p[0] for p in fam.parameters)
    assert set(fam.units) <= {"m", "m/s", "log10 Pa", "1"}
    base = fam.base(default_scene())
    train, test = fam.sample_splits(3, 2, seed=0)
    assert train.shape == (3, len(fam.names)) and test.shape == (2, len(fam.names))
    for row in np.concatenate([train, test, fam.sample(2, seed=5)]):
        design = Design.of(fam, row)
        assert design.family_name == name and design.names == fam.names
        np.testing.assert_array_equal(design.vector(), row)           # a sampled row is canonical
        again = Design.of(fam, design.vector())
        assert again == design and again.scene(base) == design.scene(base)
        scene = design.scene(base)
        assert scene.ball.radius == design.row["ball.radius"] and scene.ball.velocity == design.row["ball.velocity"]
        if fam.padded:
            assert len(scene.layers) == stack_layer_count(design.row)
        else:
            assert scene.design == tuple(design.row[n] for n in scene.design_layers)
        assert "ball.radius=" in design.label() and " mm" in design.label()


def test_the_built_in_families_are_the_two_classes():
    assert {type(f) for f in FAMILIES.values()} == {SceneFamily, StackFamily}
    stack = next(f for f in FAMILIES.values() if f.padded)
    assert stack.plans == ("e1", "e2", "e3") and next(f for f in FAMILIES.values() if not f.padded).plans == ()
    row = Design.of(stack, stack.sample(1, seed=0)[0]).row
    row["TSP.present"], row["TSP.thickness"] = 0.2, 7e-6              # off: the vector zeroes the absent layer
    vec = Design.of(stack, list(row.values())).vector()
    assert vec[stack.names.index("TSP.present")] == 0 and vec[stack.names.index("TSP.thickness")] == 0


def test_a_design_of_design_layers():
    d = Design.of(None, [40e-6, 160e-6], ("OCA1", "OCA2"))
    assert d.label() == "OCA1=40 µm, OCA2=160 µm" and d.family_name is None
    scene = d.scene(default_scene())
    assert scene.design == (40e-6, 160e-6)
    np.testing.assert_array_equal(d.vector(), [40e-6, 160e-6])


def test_a_new_family_touches_one_module(tmp_path):
    fam = ImpactorFamily()
    assert isinstance(fam, Family)
    base = fam.base(default_scene())
    train, test = sampled_splits(base, fam, n_train=3, n_test=1, seed=0)
    assert [len(train.designs), len(test.designs)] == [3, 1] and train.origin["rows"] == [0, 3]
    assert all(3e-3 <= d.scene(base).ball.radius <= 6e-3 for d in train.designs)
    with pytest.raises(DatasetError, match="finite values > 0"):     # explicit rows: checked before the lock
        explicit_split(base, fam, [[4e-3, 0.0]], "extrap")
    root = ensure_dataset(tmp_path / "toy", preset="family_tiny", family=fam, n_train=3, n_test=1, seed=0,
                          solve_fn=_fake_solve, batch=2, progress=False)
    man = load_manifest(root)
    assert man["family"] == {"parameters": [list(p) for p in fam.parameters]}
    assert man["splits"]["train"]["origin"] == {"kind": "impactor", "seed": 0, "n_total": 4, "rows": [0, 3]}
    designs = split_designs(root, "train", family=fam)
    assert designs == list(train.designs)
    got, val, tst = load_splits(root, n_train=2, n_val=1, n_test=1)
    for traj, design in zip(got + val, designs):
        assert traj.meta["family"] == "impactor" and traj.meta["scene_params"] == design.row
        assert traj.meta["scene"] == design.scene(base).to_dict()
    assert tst[0].meta["scene_params"] == test.designs[0].row
    with pytest.raises(DatasetError, match="pass its family"):   # the preset's family does not read its rows
        split_designs(root, "train")
    # resuming with the same family solves nothing
    ensure_dataset(root, preset="family_tiny", family=fam, n_train=3, n_test=1, seed=0, progress=False,
                   solve_fn=lambda *a, **k: pytest.fail("resumed a complete dataset"))


def test_split_designs_of_the_design_layers(tmp_path):
    root = ensure_dataset(tmp_path / "d", preset="tiny", designs=np.array([[40e-6, 160e-6]]), solve_fn=_fake_solve,
                          progress=False)
    assert [d.label() for d in split_designs(root, "extrap")] == ["OCA1=40 µm, OCA2=160 µm"]
    with pytest.raises(DatasetError, match="no generated split 'train'"):
        split_designs(root, "train")
