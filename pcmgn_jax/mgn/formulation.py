"""What the network predicts and how a prediction becomes the next frame: the one home of the targets.

A :class:`Formulation` is static (hashable) and fixes, per body of the scene:

- the **target** of the moving nodes (model outputs [a_x, a_y] per node; the third output is the von Mises stress of the
  next frame, for every formulation, or its log: ``stress_target``):

  ======================  ==============================  ======================================
  target                  a (physical, SI)                update (u: displacement [m], v: velocity)
  ======================  ==============================  ======================================
  ``velocity``            (u_{t+1} - u_t) / dt            u' = u + a dt            (paper)
  ``displacement``        u_{t+1} - u_t                   u' = u + a
  ``position``            X + u_{t+1} (world)             u' = a - X
  ``acceleration``        (v_{t+1} - v_t) / dt            v' = v + a dt, u' = u + v' dt
  ``total_displacement``  u_{t+1} (from the reference)    u' = a
  ======================  ==============================  ======================================

  with v_t = (u_t - u_{t-1}) / dt the frame-averaged velocity (the solver's velocity at t = 0), which is
  also the model's velocity input, in training and in a rollout alike.
- ``rigid_ball``: the ball (part 0) moves as one rigid body. Its nodes all carry the ball's mean displacement and
  velocity; the network predicts the ball's single acceleration (or other target) as an attention-weighted mean of its
  per-node outputs (a softmax over a 4th output channel of the ball nodes), so the nodes that see the contact drive the
  whole body.
- ``normalization``: ``global`` (the paper: one mean/std per channel over all nodes) or ``per_part`` (one mean/std per
  channel and node type, so the 2 MPa OLED and the 700 MPa cover glass are both O(1)).
- ``features``: ``paper`` (nodes [one-hot, world position, velocity], mesh edges [u_ij, |u_ij|, x_ij, |x_ij|]) or
  ``strain`` (nodes [one-hot, reference position, displacement, velocity], mesh edges [u_ij/|u_ij|, |u_ij|, (u_s -
  u_r)/|u_ij|, stretch (|x_ij| - |u_ij|)/|u_ij|]: the deformation is a channel of its own instead of 0.01 % of x_ij).
- ``loss_weighting``: ``nodes`` (the paper: mean over nodes) or ``parts`` (mean over parts of each part's node mean, so
  388 ball nodes or the big plate do not outvote the 30 µm OLED).
- ``panel_model``: ``dynamic`` (the layers' own displacement and velocity are inputs, their target is integrated frame
  by frame: errors accumulate over a rollout) or ``quasi_static`` (the layers are drawn at their reference configuration
  in the graph, so their state is never an input; every node carries the rigid ball's vertical displacement and velocity
  as 2 extra channels, and the layers predict their total displacement from the reference and their stress *at the
  input's time* as a function of the ball's state and the geometry (a rollout moves the ball on, then evaluates the
  panel at the ball's new state, :func:`pcmgn_jax.mgn.rollout.step`): the panel's fields are a map of the ball's motion,
  not a second dynamical system, so they cannot drift). The map is well posed where the panel's lowest eigenperiod is
  far below the contact time (docs/design.md §5.1; the measurement: docs/results/surrogate.md). The ball stays the one
  dynamical state (its acceleration is integrated). Needs ``rigid_ball`` and ``panel_target='total_displacement'``.
- ``contact_projection``: after every rollout step, the contact layer's top-surface nodes that the network put inside
  the rigid ball are moved down onto the ball's lower surface (the polyline of its downward-facing surface nodes,
  interpolated at each node's x; :func:`pcmgn_jax.mgn.rollout.project_contact`). The ball is rigid, so where its surface
  is is known exactly; a hard constraint makes the fit-free penetration the facet sagitta (h^2 / 8R, ~0.02 µm at the
  `cpu` mesh's 25 µm) instead of whatever the network left, without the penetration term's cost to the fit. Rollouts
  only: the training loss sees the network's raw output (``lambda_pen`` still penalises it there if set). Stresses are
  not changed.
- ``processor``: ``per_frame`` (the ball state is a node input, so the whole network runs every frame) or ``per_design``
  (``quasi_static`` only: the graph is drawn with the ball at its reference too, so the encoder and the message-passing
  processor see only the design and run **once per design**; the ball's state [u_ball,y, v_ball,y] goes straight to the
  decoder, a per-node MLP on [latent, ball state], which is all a rollout evaluates per frame: ~1/50 of the per-frame
  network's cost). A quasi-static panel's fields are a map of the ball's state given the design (see ``panel_model``);
  this draws that map as "the design's latent field, read out at the ball's state" (DeepONet-like: the processor is the
  branch, the ball state the trunk input). :mod:`pcmgn_jax.mgn.rollout` runs the processor once before the scan; the
  training loss sees the same network (processor + decoder) per sample, so training costs what it did.
- ``scene_features``: scene parameters given to every node as extra input channels (after the velocity), normalised like
  the other node channels (per node type with ``per_part``): ``ball_radius`` [m] sets the rigid ball's mass (∝ R³) and
  curvature, which the region-of-interest graph (the ball's lowest 0.5 mm) cannot show; ``ball_velocity`` [m/s] (the
  impact speed) is available but redundant: the speed is already the ball's velocity state; ``layer_thickness`` [m] (one
  channel per layer; the default formulation's) states the design outright: the mesh shows each layer's thickness only
  as the reference positions of its nodes, and the OLED's stress depends on the OCA thicknesses several layers and
  message-passing hops away (docs/results/surrogate.md). Constant channels (a layer that no design changes) normalise to
  0. Layer-only features are 0 on the contact pair's nodes (ball and cover glass,
  :func:`pcmgn_jax.mgn.scene_features.scene_feature_rows`). ``material`` (3 channels,
  :func:`~pcmgn_jax.mgn.scene_features.material_rows`) is each node's own part's [log10 E, nu, log10 rho], normalised
  over all nodes (:func:`~pcmgn_jax.mgn.scene_features.across_part_channels`); with ``part_identity='material'`` the
  layers' one-hot columns stay unset, so a layer is known by its material and geometry (docs/design.md §5).
- ``origin``: where the node features' positions are measured from: ``mesh`` (the mesh's coordinates, y from the plate's
  bottom), ``contact_top`` (y from the contact layer's top surface), so a layer below the contact that changes thickness
  does not move the contact zone to heights training never saw, or ``support_top`` (y from the bottom layer's top), so
  the plate's thickness moves nothing above it: with a plate every training scene shares, the same features as ``mesh``
  up to a constant, which the per-part normaliser removes (:func:`pcmgn_jax.mgn.graphs.origin_height`, docs/design.md
  §5). ``stack_thickness`` is ``layer_thickness`` on every node, the contact pair's included: with ``contact_top`` the
  ball's height no longer tells it how thick the stack below is, so it is told. Node channels, not a graph-level global,
  because the local processor has no global block and every node of a scene carries the same value (a broadcast global);
  empty (the default) for single-scene datasets, where the channel would be constant.
- ``reach``: how far a node sees within one processor pass (docs/design.md §5.3): ``local`` (the paper:
  ``message_passing_steps`` mesh hops), ``multiscale`` (a bi-stride V-cycle over ``reach_levels`` coarse levels after
  every 4th local step and the last, :mod:`pcmgn_jax.mgn.multiscale`) or ``attention`` (a physics-attention block over
  ``reach_slices`` learned slices with ``reach_heads`` heads at the same places, :mod:`pcmgn_jax.mgn.attention`). The
  hyper-parameters are ignored by ``local``.
- ``stress_target``: what the stress output is: ``linear`` (von Mises [Pa]) or ``log`` (s = log1p(vm / VM_REF), VM_REF =
  1 MPa: the 1 MPa OLED and the 100 MPa cover glass are both O(1), low-stress frames are resolved relatively; read back
  as VM_REF expm1(s) >= 0). The normaliser's statistics are s's; :mod:`pcmgn_jax.mgn.stress_target`.

Noise (training): Gaussian n on the input displacement of the noised nodes (one shared sample for a rigid ball); the
velocity input is derived from the noisy displacement (v~ = v + n/dt, as in a rollout), and the target is corrected so
the update from the noisy input lands on the clean next frame (:func:`noise_correction`).
"""
from __future__ import annotations

import dataclasses
from typing import Literal, get_args

import jax
import jax.numpy as jnp
import numpy as np

from pcmgn_jax.mgn.scene_features import PER_LAYER_FEATURES, SCENE_FEATURES
from pcmgn_jax.mgn.stress_target import StressTarget, stress_to_target

Target = Literal["velocity", "displacement", "position", "acceleration", "total_displacement"]  # --help lists them
Normalization, Features = Literal["global", "per_part"], Literal["paper", "strain"]
LossWeighting, PanelModel = Literal["nodes", "parts"], Literal["dynamic", "quasi_static"]
Processor, PartIdentity = Literal["per_frame", "per_design"], Literal["type", "material", "role"]
Origin, Reach = Literal["mesh", "contact_top", "support_top"], Literal["local", "multiscale", "attention"]
NoiseParts = Literal["none", "ball", "panel", "all"]
(TARGETS, NORMALIZATIONS, FEATURES, LOSS_WEIGHTINGS, PANEL_MODELS, PROCESSORS, PART_IDENTITIES, ORIGINS, REACHES,
 NOISE_PARTS, STRESS_TARGETS) = (get_args(t) for t in (Target, Normalization, Features, LossWeighting, PanelModel,
                                 Processor, PartIdentity, Origin, Reach, NoiseParts, StressTarget))  # the allowed values
BALL_STATE_CHANNELS = 2  # quasi_static: [u_ball,y, v_ball,y] on every node (the ball moves along the axis)
BALL_PART = 0  # scene convention: part 0 is the ball, 1.. the layers from the top (scene.py)


@dataclasses.dataclass(frozen=True)
class Formulation:
    """Static description of what the MGN predicts (a jit cache key; see the module docstring)."""

    ball_target: Target = "acceleration"      # the ball's target: velocity | displacement | position | acceleration | total_displacement
    panel_target: Target = "velocity"         # the layers' target (same choices)
    rigid_ball: bool = True                   # the ball as one rigid body driven by its contact nodes (False: every node free, the paper)
    normalization: Normalization = "per_part" # per_part (one normaliser per node type) | global (the paper)
    features: Features = "strain"             # strain (deformation channels of their own) | paper
    loss_weighting: LossWeighting = "parts"   # parts (every part counts alike) | nodes (the paper: mean over nodes)
    scene_features: tuple[str, ...] = ()      # per-scene node inputs: ball_radius, ball_velocity, layer_thickness, stack_thickness, material (flag: comma list or none)
    panel_model: PanelModel = "dynamic"       # dynamic (the layers' state integrated) | quasi_static (their fields a map of the ball's state)
    contact_projection: bool = False          # rollouts move cover-glass nodes inside the rigid ball onto its surface
    processor: Processor = "per_frame"        # per_frame (the ball state is a node input: the processor runs every frame) | per_design (quasi_static only: the processor runs once per design on the static graph, the ball state enters the decoder)
    part_identity: PartIdentity = "type"      # type (a one-hot of every part) | material (the layers known only by their 'material' scene feature: a one-hot is kept for the ball and the fixed nodes) | role (six node types whatever the layer count: ball, contact layer, film, objective layer (OLED), support, fixed; graphs.ROLES)
    reach: Reach = "local"                    # local (message passing only: message_passing_steps hops) | multiscale (+ bi-stride coarse levels, BSMS-GNN) | attention (+ physics attention over learned slices, Transolver); design §5.3
    reach_levels: int = 4                     # multiscale: coarse levels of the V-cycle
    reach_slices: int = 32                    # attention: learned slices (tokens) per graph
    reach_heads: int = 4                      # attention: heads of the attention among the slices (divides latent_size)
    origin: Origin = "mesh"                   # mesh (node positions in the mesh's coordinates, y from the plate's bottom) | contact_top (y from the contact layer's top surface: layers below it may change thickness without moving the nodes above in the features) | support_top (y from the bottom layer's top: the plate's thickness moves nothing above it)
    stress_target: StressTarget = "linear"    # linear (the stress output is von Mises [Pa]) | log (log1p(vm / 1 MPa): the 1 MPa OLED and the 100 MPa cover glass both O(1), low-stress frames resolved relatively; mgn/stress_target.py)

    def __post_init__(self):
        bad = [f for f in self.scene_features if f not in SCENE_FEATURES]
        if bad:
            raise ValueError(f"formulation: scene_features {bad} must be among {sorted(SCENE_FEATURES)}")
        for name, allowed in (("ball_target", TARGETS), ("panel_target", TARGETS),
                              ("normalization", NORMALIZATIONS), ("features", FEATURES),
                              ("loss_weighting", LOSS_WEIGHTINGS), ("panel_model", PANEL_MODELS),
                              ("processor", PROCESSORS), ("part_identity", PART_IDENTITIES),
                              ("origin", ORIGINS), ("reach", REACHES), ("stress_target", STRESS_TARGETS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"formulation: {name}={getattr(self, name)!r} must be one of {allowed}")
        for name in ("reach_levels", "reach_slices", "reach_heads"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise ValueError(f"formulation: {name}={getattr(self, name)!r} must be an integer >= 1")
        if self.panel_model == "quasi_static" and not (self.rigid_ball and self.panel_target == "total_displacement"):
            raise ValueError("formulation: panel_model='quasi_static' needs rigid_ball=True and "
                             f"panel_target='total_displacement' (got rigid_ball={self.rigid_ball}, "
                             f"panel_target={self.panel_target!r}): a layer whose state is not an input "
                             "can only predict where it is, not how it moves on")
        if self.part_identity in ("material", "role") and "material" not in self.scene_features:
            raise ValueError(f"formulation: part_identity={self.part_identity!r} needs 'material' among scene_features "
                             f"(got {self.scene_features}): without it the layers' nodes could not tell their part")
        if self.part_identity == "role" and set(self.scene_features) & set(PER_LAYER_FEATURES):
            raise ValueError(f"formulation: part_identity='role' takes no per-layer scene features "
                             f"{sorted(set(self.scene_features) & set(PER_LAYER_FEATURES))} (one channel per layer: "
                             "a 7-layer stack would need more inputs than a 5-layer one); use own_thickness, "
                             "layer_depth, total_thickness")
        if self.processor == "per_design" and self.panel_model != "quasi_static":
            raise ValueError("formulation: processor='per_design' needs panel_model='quasi_static' (got "
                             f"{self.panel_model!r}): only a panel drawn at its reference has a graph that "
                             "does not change within a rollout")

    @property
    def node_extra(self) -> int:
        """Node input channels beyond the features' own and the scene features (the ball state)."""
        return BALL_STATE_CHANNELS if self.panel_model == "quasi_static" else 0

    @property
    def hierarchy_levels(self) -> int:
        """Coarse levels the graph inputs must carry (:func:`pcmgn_jax.mgn.inputs.design_topology`):
        ``reach_levels`` for ``reach='multiscale'``, else 0."""
        return self.reach_levels if self.reach == "multiscale" else 0

    @property
    def decoder_condition(self) -> int:
        """Node input channels (the last ones) that bypass the processor and enter the decoder:
        the ball state with ``processor='per_design'``, else 0."""
        return BALL_STATE_CHANNELS if self.processor == "per_design" else 0

    @property
    def output_size(self) -> int:
        """Model outputs per node: a_x, a_y, von Mises (+ the rigid ball's attention score)."""
        return 4 if self.rigid_ball else 3

    def replace(self, **kw) -> "Formulation":
        return dataclasses.replace(self, **kw)


FORMULATIONS = {
    # the paper as published: every node predicts its next velocity, one normaliser, raw features
    "paper": Formulation(ball_target="velocity", panel_target="velocity", rigid_ball=False,
                         normalization="global", features="paper", loss_weighting="nodes"),
    # the project's default: each body modelled as what it is -- a rigid ball (one acceleration), a
    # quasi-static panel (its fields as a map of the ball's state and the geometry)
    "default": Formulation(panel_target="total_displacement", panel_model="quasi_static", contact_projection=True,
                           scene_features=("layer_thickness",)),
    # the previous default: the layers as a second dynamical system (velocity target, own state as input)
    "dynamic": Formulation(),
}
# the default with the per-design processor (the cpu main job's): the message passing once per design, the
# ball state read out by the decoder, so a rollout costs one network pass + a decoder per frame
FORMULATIONS["realtime"] = FORMULATIONS["default"].replace(processor="per_design")


def _xp(a):
    return np if isinstance(a, np.ndarray) else jnp


def per_node_target(kind: str, *, points, u_prev, u, u_next, dt: float):
    """Physical target (N, 2) of ``kind`` for one step (see the table). NumPy or JAX arrays."""
    if kind == "velocity":
        return (u_next - u) / dt
    if kind == "displacement":
        return u_next - u
    if kind == "position":
        return points + u_next
    if kind == "acceleration":
        return (u_next - 2.0 * u + u_prev) / (dt * dt)
    if kind == "total_displacement":
        return u_next
    raise ValueError(f"target must be one of {TARGETS}, got {kind!r}")


def apply_target(kind: str, *, points, u, v, a, dt: float):
    """Inverse of :func:`per_node_target`: (u', v') from the physical output ``a`` (N, 2)."""
    if kind == "velocity":
        u_next = u + a * dt
    elif kind == "displacement":
        u_next = u + a
    elif kind == "position":
        u_next = a - points
    elif kind == "acceleration":
        u_next = u + (v + a * dt) * dt
    elif kind == "total_displacement":
        u_next = a
    else:
        raise ValueError(f"target must be one of {TARGETS}, got {kind!r}")
    return u_next, (u_next - u) / dt


def noise_correction(kind: str, noise, dt: float):
    """What to add to the clean target of ``kind`` when the input displacement carries ``noise`` [m]
    (and the velocity input noise/dt), so the update from the noisy input lands on the clean frame."""
    if kind == "velocity":
        return -noise / dt
    if kind == "displacement":
        return -noise
    if kind == "acceleration":
        return -2.0 * noise / (dt * dt)
    if kind in ("position", "total_displacement"):
        return jnp.zeros_like(noise)
    raise ValueError(f"target must be one of {TARGETS}, got {kind!r}")


def previous_displacement(displacement, velocity, t: int, dt: float):
    """u_{t-1} (N, 2): the stored frame, or u_0 - v_0 dt before the first frame (velocity input = v_0)."""
    if t == 0:
        return displacement[0] - velocity[0] * dt
    return displacement[t - 1]


def is_ball(node_type) -> np.ndarray:
    return np.asarray(node_type) == BALL_PART


def rigid_mean(field, ball_mask, segments=None):
    """Mean of a (N, 2) field over the ball nodes (``ball_mask`` (N,) bool). NumPy or JAX.

    ``segments``: None for one graph -> (2,); or ``(node_graph (N,) int, n_graph)`` for a disjoint union
    of graphs (JAX only) -> (n_graph, 2), one mean per graph over its own ball nodes (0 for a graph
    without ball nodes, e.g. padding).
    """
    xp = _xp(field)
    w = xp.asarray(ball_mask, field.dtype)[:, None]
    if segments is None:
        return xp.sum(field * w, axis=0) / xp.maximum(xp.sum(w), 1.0)
    node_graph, n_graph = segments
    total = jax.ops.segment_sum(field * w, node_graph, num_segments=n_graph)
    count = jax.ops.segment_sum(w, node_graph, num_segments=n_graph)
    return total / jnp.maximum(count, 1.0)


def per_body(body_values, segments=None):
    """A rigid body's value(s) broadcast to every node: (2,) -> (1, 2), or (G, 2) -> (N, 2) by graph."""
    if segments is None:
        return body_values[None]
    return body_values[segments[0]]


def axial(values):
    """``values`` (..., 2) with the x component zeroed: the rigid ball's motion is along the symmetry axis.

    Every scene of this project is a half model whose symmetry axis x = 0 passes through the ball's
    centre (axisymmetric or plane strain), so the rigid ball's x motion is zero by symmetry; in the
    solver's data it is ~1e-10 m of elastic asymmetry, and normalising that channel by its own spread
    would turn round-off into an O(1) random input and target."""
    xp = _xp(values)
    return values * xp.asarray([0.0, 1.0], dtype=values.dtype)


def rigidify(field, ball_mask, segments=None):
    """``field`` (a displacement or velocity) with the ball nodes replaced by their (per-graph) mean
    vertical motion (a rigid body on the symmetry axis, :func:`axial`). NumPy or JAX."""
    xp = _xp(field)
    mean = axial(per_body(rigid_mean(field, ball_mask, segments), segments))
    return xp.where(xp.asarray(ball_mask)[:, None], mean, field)


def model_inputs(form: Formulation, ball_mask, u, v, segments=None):
    """What the network sees of a state: (u_in, v_in (N, 2), extra (N, BALL_STATE_CHANNELS) or None).

    ``dynamic``: the state itself, no extra channels. ``quasi_static``: the layers at their reference
    (u = v = 0; the contact search then runs against the reference cover glass, so the graph is a
    function of the ball's state alone), the ball as it is, and every node carrying its graph's rigid
    ball's vertical displacement [m] and velocity [m/s] (``segments``: see :func:`rigid_mean`; the ball
    moves along the symmetry axis, :func:`axial`). With ``processor='per_design'`` the ball too is drawn
    at its reference (its state is only in the extra channels, which the model hands to its decoder), so
    the graph is the same in every frame of a design. NumPy or JAX.
    """
    if form.panel_model != "quasi_static":
        return u, v, None
    xp = _xp(u)
    ball = xp.asarray(ball_mask)[:, None]
    u_in, v_in = xp.where(ball, u, 0.0), xp.where(ball, v, 0.0)
    if form.processor == "per_design":  # the ball at its reference too: the graph is the design's alone
        u_in, v_in = xp.zeros_like(u), xp.zeros_like(v)
    state = xp.concatenate([per_body(rigid_mean(u, ball_mask, segments), segments)[:, 1:],
                            per_body(rigid_mean(v, ball_mask, segments), segments)[:, 1:]], axis=-1)
    return u_in, v_in, xp.broadcast_to(state, (u.shape[0], BALL_STATE_CHANNELS))


def training_sample(form: Formulation, ball_mask, *, points, u_prev, u, u_next, vm_next, dt: float,
                    vm=None) -> dict:
    """Inputs and physical targets of one step (NumPy, host side).

    Returns dict(u (N,2), v (N,2) inputs; target (N,3) per-node [a_x, a_y, von Mises (its log: ``stress_target``)];
    ball (2,) the rigid ball's target (zeros unless ``form.rigid_ball``)). With a rigid ball, the ball rows of every
    displacement are its mean (the ball is rigid to ~0.005 µm in the solver's data).

    A ``quasi_static`` panel's targets are its fields at the input's own time (displacement ``u`` and
    stress ``vm`` (N,) [Pa], needed then): the panel is a map of the ball's current state, so in a rollout
    it is evaluated at the ball's next state (:func:`pcmgn_jax.mgn.rollout.step`) rather than one frame
    behind it (a frame is 2.5 µm of ball travel at impact speed).
    """
    f = lambda a: np.asarray(a, np.float64)  # noqa: E731
    points, u_prev, u, u_next = f(points), f(u_prev), f(u), f(u_next)
    ball = np.asarray(ball_mask, bool)
    if form.rigid_ball:
        u_prev, u, u_next = (rigidify(a, ball) for a in (u_prev, u, u_next))
    kw = dict(points=points, u_prev=u_prev, u=u, u_next=u_next, dt=dt)
    panel_kw = kw
    if form.panel_model == "quasi_static":  # the panel's fields at the input's own time
        if vm is None:
            raise ValueError("training_sample: a quasi_static panel needs the stress at the input's time (vm)")
        panel_kw, vm_next = dict(kw, u_next=u), vm
    a = np.where(ball[:, None], per_node_target(form.ball_target, **kw), per_node_target(form.panel_target, **panel_kw))
    vm_next = stress_to_target(form.stress_target, f(vm_next))  # [Pa], or its log (stress_target)
    rigid = np.zeros(2)
    if form.rigid_ball:
        rigid = per_node_target(form.ball_target, points=rigid_mean(points, ball), u_prev=rigid_mean(u_prev, ball),
                                u=rigid_mean(u, ball), u_next=rigid_mean(u_next, ball), dt=dt)
    return dict(u=u, v=(u - u_prev) / dt, target=np.concatenate([a, vm_next[:, None]], axis=-1), ball=rigid)


def add_noise(form: Formulation, ball_mask, sample: dict, noise, dt: float, segments=None) -> dict:
    """``sample`` (from :func:`training_sample`, JAX arrays) with ``noise`` (N, 2) [m] on the input
    displacement, the velocity input v + noise/dt, and targets corrected (module docstring). With a
    rigid ball the caller passes one shared noise vector on all ball rows (of each graph: ``segments``
    of a disjoint union, see :func:`rigid_mean`; the ball target is then (G, 2))."""
    ball = jnp.asarray(ball_mask)[:, None]
    if form.rigid_ball:
        noise = jnp.where(ball, axial(noise), noise)  # the rigid ball stays on the symmetry axis
    corr = jnp.where(ball, noise_correction(form.ball_target, noise, dt),
                     noise_correction(form.panel_target, noise, dt))
    out = dict(sample, u=sample["u"] + noise, v=sample["v"] + noise / dt,
               target=jnp.asarray(sample["target"]).at[:, :2].add(corr))
    if form.rigid_ball:
        out["ball"] = sample["ball"] + noise_correction(form.ball_target, rigid_mean(noise, ball_mask, segments), dt)
    return out


def integrate(form: Formulation, ball_mask, *, points, u, v, a, a_ball, dt: float, segments=None):
    """Next (u', v') (N, 2) from physical per-node outputs ``a`` (N, 2) and the rigid ball's ``a_ball``
    ((2,), or (G, 2) per graph with ``segments``; see :func:`rigid_mean`; ignored unless
    ``form.rigid_ball``). Boundary conditions are the caller's."""
    ball = jnp.asarray(ball_mask)[:, None]
    un, vn = apply_target(form.panel_target, points=points, u=u, v=v, a=a, dt=dt)
    if form.rigid_ball:
        mean = lambda f: rigid_mean(f, ball_mask, segments)  # noqa: E731
        ub, vb = apply_target(form.ball_target, points=mean(points), u=mean(u), v=mean(v), a=a_ball, dt=dt)
        ub, vb = axial(ub), axial(vb)
        return jnp.where(ball, per_body(ub, segments), un), jnp.where(ball, per_body(vb, segments), vn)
    ub, vb = apply_target(form.ball_target, points=points, u=u, v=v, a=a, dt=dt)
    return jnp.where(ball, ub, un), jnp.where(ball, vb, vn)
