"""The rom family: ``rom``, a field reduced-order model across meshes (a scene family, each scene its own
mesh), its stack form (:class:`StackRom`) and ``rom_contact`` (:class:`RomContact`).

    r = fit("rom", train_trajs)                 # trajectories with meta['scene_params'] (registry.fit does the same)
    us, vms = r.predict_trajectories(trajs)     # lists: u (T, N_b, 2) [m], vm (T, N_b) [Pa], each on its mesh
    r.warnings                                  # queries outside the training box (strings for metrics.json)

1. Reference mesh: the FIRST training trajectory's mesh (points, node_part, scene). Every training scene's
   fields are carried onto it by :func:`transfer.transfer_fields` (part-relative coordinates, the rule
   of the ``nearest`` baseline).
2. Snapshots: per scene the row [u / s_u, vm / s_vm] of every frame and reference node (T·N·3 values);
   s_u [m] and s_vm [Pa] are the RMS of the centred u and vm snapshots (1 where a field never varies),
   so the two fields are each O(1).
3. POD + GP (:class:`surface_fit.PodGP`): SVD of the centred snapshots, the fewest modes holding
   :data:`POD_ENERGY` of sum S², one GP with the kriging kernel on their coefficients over the scene
   parameters scaled to [-1, 1] (:class:`surface_fit.ParameterBox`).
4. Prediction: the GP mean at a query's scene parameters, unscaled, carried from the reference mesh to
   the query's mesh by :func:`transfer.transfer_fields` (the identity when it is the reference mesh).
"""
from __future__ import annotations

import dataclasses
import time
from typing import Sequence

import numpy as np

from pcmgn_jax.surrogates.correction import rigid_contact
from pcmgn_jax.surrogates.inputs import TrainingScenes, part_names_of, trajectory_labels
from pcmgn_jax.surrogates.kinds import CannotAnswer
from pcmgn_jax.surrogates.objective import FromFields
from pcmgn_jax.surrogates.surface_fit import ParameterBox, PodGP, not_applicable
from pcmgn_jax.surrogates.transfer import transfer_fields

POD_ENERGY = 0.9999   # fraction of the centred snapshots' energy (sum of squared singular values) kept


def _spread(a: np.ndarray) -> float:
    """RMS of the snapshots (B, ...) about their mean snapshot, 1.0 when they do not vary."""
    s = float(np.sqrt(np.mean((a - a.mean(0)) ** 2)))
    return s if s > 0 else 1.0


class Rom(FromFields):
    """POD of training fields on a reference mesh + a GP on the coefficients (module docstring).
    Attributes: ``names`` the scene parameters, ``ref`` the reference trajectory, ``pod`` the fitted
    :class:`PodGP` (``n_modes``, ``energy_kept``), ``u_scale`` [m], ``vm_scale`` [Pa], ``fit_seconds``,
    ``warnings`` the queries outside the training box so far (strings for metrics.json)."""

    name = "rom"

    def __init__(self, train_trajs: Sequence, *, energy: float = POD_ENERGY):
        trajs = list(train_trajs)
        if not trajs:
            raise ValueError("rom: needs training trajectories")
        t0 = time.perf_counter()
        self.ref = trajs[0]
        self._check_frames(trajs)                             # one layer list, one window: else no map
        self.scenes = TrainingScenes(trajs)
        self.names, x = self.scenes.names, self.scenes.x
        self.box = ParameterBox(x, self.names, model=self.name)
        self.warnings = self.box.warnings                     # queries outside the box (for metrics.json)
        if (why := not_applicable("kriging", len(trajs), self.box.n_inputs)) is not None:
            raise ValueError(f"rom: {why}")
        u, vm = zip(*(self._carry(t, self.ref, t.displacement, t.von_mises) for t in trajs))
        u, vm = np.stack(u), np.stack(vm)                     # (B, T, N_ref, 2) [m], (B, T, N_ref) [Pa]
        self.u_scale, self.vm_scale = _spread(u), _spread(vm)
        B = len(trajs)
        Y = np.concatenate([u.reshape(B, -1) / self.u_scale, vm.reshape(B, -1) / self.vm_scale], axis=1)
        self.pod = PodGP(self.box.scale(x), Y, energy=energy)
        self.fit_seconds = time.perf_counter() - t0

    @property
    def pod_modes(self) -> int:
        return int(self.pod.n_modes)

    def predict(self, designs_m):
        raise CannotAnswer(self.name, "fields at designs alone",
                           "it predicts trajectories (their scene parameters and meshes): use predict_trajectories")

    def _check_frames(self, trajs):
        for label, t in zip(trajectory_labels(trajs), trajs):
            if part_names_of(t) != part_names_of(self.ref):
                raise ValueError(f"rom: the meshes do not map: {label} has the parts {list(part_names_of(t))}, the "
                                 f"reference {trajectory_labels([self.ref])[0]} {list(part_names_of(self.ref))} (a "
                                 "stack of other layers has no place on the reference mesh)")
            if t.n_frames != self.ref.n_frames:
                raise ValueError(f"rom: {label} has {t.n_frames} frames, the reference "
                                 f"{trajectory_labels([self.ref])[0]} {self.ref.n_frames}")
            if "scene" not in t.meta:
                raise ValueError(f"rom: {label} has no meta['scene'] (needed to carry fields between meshes)")

    @staticmethod
    def _carry(src, dst, u, vm) -> tuple[np.ndarray, np.ndarray]:
        """Fields u (T, N_src, 2) [m], vm (T, N_src) [Pa] on ``src``'s mesh carried to ``dst``'s."""
        u, vm = np.asarray(u, np.float64), np.asarray(vm, np.float64)
        if src is dst or (np.array_equal(src.points, dst.points) and np.array_equal(src.node_part, dst.node_part)
                          and src.meta["scene"] == dst.meta["scene"]):
            return u, vm
        return transfer_fields(dataclasses.replace(src, displacement=u, von_mises=vm),
                               dst.points, dst.node_part, dst.meta["scene"])

    def predict_trajectories(self, trajs: Sequence) -> tuple[list, list]:
        """Per trajectory (on its own mesh, at its meta['scene_params']): displacement (T, N, 2) [m] and
        von Mises (T, N) [Pa]. A trajectory missing a scene parameter raises ValueError naming it; one
        outside the training box, or changing what training held fixed, is answered and recorded in
        ``warnings`` (:mod:`scene_inputs`)."""
        trajs = list(trajs)
        x = self.scenes.inputs(trajs, self.box.note)
        self._check_frames(trajs)
        Y = self.pod.predict(self.box.scale(x, trajectory_labels(trajs)))[0]
        shape = (self.ref.n_frames, self.ref.n_nodes)
        n_u = 2 * int(np.prod(shape))
        us, vms = [], []
        for t, row in zip(trajs, Y):
            u, vm = self._carry(self.ref, t, row[:n_u].reshape(shape + (2,)) * self.u_scale,
                                row[n_u:].reshape(shape) * self.vm_scale)
            us.append(u)
            vms.append(vm)
        return us, vms


class StackRom(FromFields):
    """The rom where meshes map: one :class:`Rom` per layer list of the training scenes (a stack family),
    each fitted on the training scenes with that list when a query first needs it; a query whose layer list
    no training scene has raises ValueError (``rom: the meshes do not map``). ``fit_seconds`` sums the fits,
    ``warnings`` pools theirs, ``pod_modes`` {layer list: modes}."""

    name = "rom"

    def __init__(self, train_trajs: Sequence, *, energy: float = POD_ENERGY):
        self.groups: dict[tuple, list] = {}
        for t in train_trajs:
            self.groups.setdefault(part_names_of(t), []).append(t)
        self.energy, self.roms, self.fit_seconds, self.warnings = energy, {}, 0.0, []

    def _rom(self, parts: tuple, label: str) -> Rom:
        if parts not in self.roms:
            if parts not in self.groups:
                raise ValueError(f"rom: the meshes do not map: no training scene has the parts {list(parts)} of "
                                 f"{label} (a stack of other layers has no place on a training mesh)")
            self.roms[parts] = Rom(self.groups[parts], energy=self.energy)
            self.fit_seconds += self.roms[parts].fit_seconds
        return self.roms[parts]

    @property
    def pod_modes(self) -> dict[str, int]:
        return {"/".join(parts[1:]): int(r.pod.n_modes) for parts, r in self.roms.items()}

    predict = Rom.predict

    def predict_trajectories(self, trajs: Sequence) -> tuple[list, list]:
        """As :meth:`Rom.predict_trajectories`, each trajectory by the rom of its own layer list."""
        us, vms = [], []
        for label, t in zip(trajectory_labels(trajs), trajs):
            rom = self._rom(part_names_of(t), label)
            (u,), (vm,) = rom.predict_trajectories([t])
            us.append(u)
            vms.append(vm)
            self.warnings += [w for w in rom.warnings if w not in self.warnings]
        return us, vms


def fit_rom(train_trajs: Sequence, *, energy: float = POD_ENERGY) -> Rom | StackRom:
    """A :class:`Rom` over training scenes of one layer list, else a :class:`StackRom`."""
    return Rom(train_trajs, energy=energy) if len({part_names_of(t) for t in train_trajs}) <= 1 \
        else StackRom(train_trajs, energy=energy)


class RomContact(FromFields):
    """``rom_contact``: the rom's fields with the MGN rollout's hard contact (a rigid ball, the cover glass
    projected out of it: :func:`correction.rigid_contact`), so a baseline-corrected MGN (``residual_of=rom``)
    is measured against what the constraint alone gives. ``pod_modes``, ``warnings``, ``fit_seconds``: the rom's."""

    name = "rom_contact"

    def __init__(self, rom: Rom | StackRom):
        self.rom = rom

    fit_seconds = property(lambda self: self.rom.fit_seconds)
    warnings = property(lambda self: self.rom.warnings)
    pod_modes = property(lambda self: self.rom.pod_modes)

    predict = Rom.predict

    def predict_trajectories(self, trajs: Sequence) -> tuple[list, list]:
        """The rom's fields, the displacement through :func:`correction.rigid_contact` on each query's mesh."""
        us, vms = self.rom.predict_trajectories(trajs)
        return [rigid_contact(t, u) for t, u in zip(trajs, us)], vms


def fit(kind: str, train_trajs: Sequence, *, energy: float = POD_ENERGY, queries=(), readings=None,
        part=None) -> Rom | StackRom | RomContact:
    """``rom`` (:func:`fit_rom`) or ``rom_contact`` (:class:`RomContact` of it) fitted on ``train_trajs``
    (``queries``, ``readings``, ``part``: every trajectory family takes them; the rom answers any mesh and reading)."""
    rom = fit_rom(train_trajs, energy=energy)
    return RomContact(rom) if kind == "rom_contact" else rom

