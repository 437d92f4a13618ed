"""Differentiable MLS-MPM dough simulator with rigid SDF tools (Taichi).

Physics (env_spec.md section 1): APIC transfers with quadratic B-splines on a
regular grid over the unit cube (y up); fixed-corotated elasticity; von Mises
plasticity on Hencky strain with radial return; Coulomb friction on the ground;
free-slip walls; rigid tools coupled on grid nodes through their SDF with
Coulomb friction and optional soft contact.

Layout. The simulator holds one environment step: ``substeps + 1`` frames of
particle state ``x, v, C, F`` and tool poses. ``step`` runs the substeps and
moves the last frame back to frame 0; ``record_step`` also writes what the
step's adjoint needs into host arrays. Reverse mode differentiates one
environment step at a time from its record (kept from the forward pass while
memory allows, else recorded anew from the step's checkpoint), substep by
substep (see ``pasta.sim.autodiff``).

Compile-time values: grid size, particle count, dt and the kinds of tools.
Runtime values (no recompile): material, gravity, ground friction, contact
softness and every tool size, friction and action scale.
"""


import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import taichi as ti

from pasta.config.schema import MaterialConfig, SimConfig, ToolConfig
from pasta.sim.quaternion import axis_angle_to_quat, quat_mul, quat_normalised, quat_to_matrix
from pasta.sim.runtime import ensure_taichi
from pasta.sim.shapes import floor_height
from pasta.sim.svd3 import fast_svd
from pasta.sim.tool_geometry import box_sdf_normal, capsule_sdf_normal, knife_sdf_normal

ACTION_DIMS = {"box": 6, "knife": 3, "gripper": 7, "rolling_pin": 6}
SINGULAR_VALUE_FLOOR = 0.05
SVD_GAP_FLOOR = 1e-6
# A particle's slot of a frame in a recorded step (MPMSimulator.record_step): where each quantity starts
# among its RECORD_CHANNELS floats. x, v, the trial F's singular values, the post-plastic ones and the
# deviatoric Hencky strain (3 each), then C, F and the SVD's U and V (3 x 3, row by row).
RECORD_LAYOUT = {"x": 0, "v": 3, "sig": 6, "sig_plastic": 9, "strain_dev": 12, "C": 15, "F": 24, "U": 33, "V": 42}
RECORD_CHANNELS = 51
# Floats per grid node of a recorded substep (MPMSimulator.record_step): mass, momentum, new velocity.
GRID_CHANNELS = 7
MAX_SPEED = 1e3
# Soft contact acts where exp(-softness * sdf) exceeds this; the official 0.1 cut-off makes the
# contact force jump, which finite differences see and adjoints do not.
SOFT_CONTACT_CUTOFF = 1e-3
# The ordered P2G scatters fixed chunks of particles, each serially into its own grid, and sums the
# chunks' grids in chunk order: a fixed summation order whatever the number of threads.
P2G_CHUNKS = 4


@ti.func
def taichi_svd(F):
    """Taichi's built-in iterative 3x3 SVD (``ti.svd``) in float32: (U, sig, V), each (3, 3)."""
    return ti.svd(F, ti.f32)


# The 3x3 SVDs a simulator may use (``SimConfig.svd``), all in ``ti.svd``'s convention.
SVD_METHODS = {"taichi": taichi_svd, "fast": fast_svd}


@ti.func
def svd_adjoint_in_frame(sig, u_skew, v_skew, g_sig):
    """The adjoint of ``F = U diag(sig) V^T`` in the singular frames, ``U^T g_F V`` (3, 3), given the
    singular values ``sig`` (3,), ``u_skew = U^T g_U - g_U^T U``, ``v_skew = V^T g_V - g_V^T V`` (3, 3) and
    the singular values' adjoint (3,): the closed form of the SVD's derivative, with the gaps between
    squared singular values kept at least ``SVD_GAP_FLOOR`` away from zero. Serves every method of
    ``SVD_METHODS``.
    """
    X = ti.Matrix([[g_sig[0], 0.0, 0.0], [0.0, g_sig[1], 0.0], [0.0, 0.0, g_sig[2]]])
    for i, j in ti.static(ti.ndrange(3, 3)):
        if ti.static(i != j):
            gap = sig[j] ** 2 - sig[i] ** 2
            gap = ti.select(gap >= 0.0, ti.max(gap, SVD_GAP_FLOOR), ti.min(gap, -SVD_GAP_FLOOR))
            X[i, j] = (u_skew[i, j] * sig[j] + sig[i] * v_skew[i, j]) / gap
    return X


@ti.func
def bspline_weights(fx):
    """Quadratic B-spline weights (3, 3) of a particle at fx (3,) in [0.5, 1.5) cells from its lowest
    stencil node: entry [i, d] for offset i along axis d."""
    return ti.Matrix.rows([0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2])


@ti.func
def bspline_slopes(fx):
    """d(bspline_weights)/d(fx), (3, 3), laid out as :func:`bspline_weights`."""
    return ti.Matrix.rows([fx - 1.5, -2.0 * (fx - 1.0), fx - 0.5])


@ti.func
def node_weight_and_gradient(w, slope, i: ti.template(), j: ti.template(), k: ti.template(), inv_dx):
    """Weight of stencil node (i, j, k) and its gradient (3,) with respect to the particle position (world
    units), from :func:`bspline_weights` ``w`` and :func:`bspline_slopes` ``slope``."""
    wx, wy, wz = w[i, 0], w[j, 1], w[k, 2]
    gx, gy, gz = slope[i, 0], slope[j, 1], slope[k, 2]
    return wx * wy * wz, inv_dx * ti.Vector([gx * wy * wz, wx * gy * wz, wx * wy * gz])


class SimulationError(RuntimeError):
    """The simulation produced NaN or runaway values."""


class ActionError(ValueError):
    """An action is NaN, out of [-1, 1] or of the wrong size."""


@dataclass(frozen=True)
class SimLayout:
    """The compile-time shape of a simulator: what a compiled kernel depends on."""

    n_grid: int
    n_particles: int
    dt_s: float
    substeps: int
    tool_kinds: tuple[str, ...]
    differentiable: bool
    collisions: tuple[tuple[int, int], ...] = ()
    static_tools: tuple[bool, ...] = ()
    serial_p2g: bool = True
    svd: str = "taichi"


@ti.data_oriented
class MPMSimulator:
    """MLS-MPM simulator for one dough and a fixed set of tools.

    Args:
        layout: grid size, particle count, dt, substeps per step, tool kinds, the SVD method.
        lower_bound_cells: particles are clamped to ``[max(1, lower) * dx, 1 - 3 dx]``.
        boundary_cells: thickness of the wall band in grid cells.
        arch: Taichi architecture, ``"cpu"``, ``"cuda"`` or ``"auto"`` (:func:`ensure_taichi`).
    """

    def __init__(self, layout: SimLayout, lower_bound_cells: int = 0, boundary_cells: int = 3, arch: str = "cpu"):
        ensure_taichi(arch)
        self.layout = layout
        self.serial_p2g = layout.serial_p2g
        if layout.svd not in SVD_METHODS:
            raise ValueError(f"svd must be one of {sorted(SVD_METHODS)}, got {layout.svd!r}")
        self.decompose = SVD_METHODS[layout.svd]  # (U, sig, V) of a 3x3 matrix, a Taichi function
        self.n = layout.n_particles
        self.n_grid = layout.n_grid
        self.dx = 1.0 / layout.n_grid
        self.inv_dx = float(layout.n_grid)
        self.dt = layout.dt_s
        self.substeps = layout.substeps
        self.n_frames = layout.substeps + 1
        self.tool_kinds = layout.tool_kinds
        self.n_tools = len(layout.tool_kinds)
        self.differentiable = layout.differentiable
        # Host memory a differentiable episode may keep so that its backward pass need not record the steps
        # anew (pasta.sim.autodiff; SimConfig.adjoint_memory_mb, set by simulator_for).
        self.adjoint_memory_bytes = 0
        self._spare_records: list[dict[str, np.ndarray]] = []  # buffers of released recorded steps
        # What advance writes to when it records nothing (its record arguments must still be arrays).
        self._no_record = (np.zeros(1, np.float32), np.zeros((1, 1), np.float32), np.zeros((1, 2, 3), np.int32))
        self._loaded_step: dict[str, np.ndarray] | None = None  # the recorded step substep_grad differentiates
        self.boundary_cells = boundary_cells
        self.p_vol = (0.5 * self.dx) ** 2
        self.x_low = max(1, lower_bound_cells) * self.dx
        self.x_high = 1.0 - 3.0 * self.dx

        static = layout.static_tools or (False,) * self.n_tools
        offsets, total = [], 0
        for kind, is_static in zip(self.tool_kinds, static, strict=True):
            offsets.append(total)
            total += 0 if is_static else ACTION_DIMS[kind]
        self.static_tools = static
        self.action_offsets = tuple(offsets)
        self.action_dim = total

        grad = self.differentiable
        frames, n, g = self.n_frames, self.n, self.n_grid
        n_tools = max(self.n_tools, 1)
        self.x = ti.Vector.field(3, ti.f32, shape=(frames, n), needs_grad=grad)
        self.v = ti.Vector.field(3, ti.f32, shape=(frames, n), needs_grad=grad)
        self.C = ti.Matrix.field(3, 3, ti.f32, shape=(frames, n), needs_grad=grad)
        self.F = ti.Matrix.field(3, 3, ti.f32, shape=(frames, n), needs_grad=grad)
        # The APIC affine matrix of each substep (one frame when not differentiable). The adjoint pass reads
        # the states, SVDs and return mappings from a recorded step (MPMSimulator.record_step) instead.
        self.affine = ti.Matrix.field(3, 3, ti.f32, shape=(frames if grad else 1, n))
        self.grid_m = ti.field(ti.f32, shape=(g, g, g), needs_grad=grad)
        self.grid_v_in = ti.Vector.field(3, ti.f32, shape=(g, g, g), needs_grad=grad)
        self.grid_v_out = ti.Vector.field(3, ti.f32, shape=(g, g, g), needs_grad=grad)
        # P2G's per-chunk grids: momentum (0:3) and mass (3) of chunk c at node (i, j, k), zero between
        # kernels (G2P's adjoint passes the grid velocity adjoints through them too); the box of stencil
        # nodes of each chunk's particles (lowest and highest corner, inclusive) and of all particles
        # (``active_lo``, ``active_hi``): the grid loops visit only that box.
        self.p2g_chunks = P2G_CHUNKS if self.serial_p2g else 1
        self.grid_part = ti.Vector.field(4, ti.f32, shape=(self.p2g_chunks, g, g, g))
        self.chunk_lo = ti.Vector.field(3, ti.i32, shape=self.p2g_chunks)
        self.chunk_hi = ti.Vector.field(3, ti.i32, shape=self.p2g_chunks)
        self.active_lo = ti.Vector.field(3, ti.i32, shape=())
        self.active_hi = ti.Vector.field(3, ti.i32, shape=())

        self.tool_pos = ti.Vector.field(3, ti.f32, shape=(frames, n_tools), needs_grad=grad)
        self.tool_rot = ti.Vector.field(4, ti.f32, shape=(frames, n_tools), needs_grad=grad)
        self.tool_gap = ti.field(ti.f32, shape=(frames, n_tools), needs_grad=grad)
        self.action = ti.field(ti.f32, shape=max(self.action_dim, 1), needs_grad=grad)

        # Runtime parameters: changing them needs no recompile.
        self.mu = ti.field(ti.f32, shape=())
        self.lam = ti.field(ti.f32, shape=())
        self.yield_stress = ti.field(ti.f32, shape=())
        self.density = ti.field(ti.f32, shape=())
        self.ground_friction = ti.field(ti.f32, shape=())
        self.gravity = ti.Vector.field(3, ti.f32, shape=())
        self.softness = ti.field(ti.f32, shape=())
        self.tool_expel_rate = ti.field(ti.f32, shape=n_tools)
        self.tool_half = ti.Vector.field(3, ti.f32, shape=n_tools)
        self.tool_radius = ti.field(ti.f32, shape=n_tools)
        self.tool_half_length = ti.field(ti.f32, shape=n_tools)
        self.tool_blade_depth = ti.field(ti.f32, shape=n_tools)
        self.tool_blade_slope = ti.field(ti.f32, shape=n_tools)
        self.tool_min_gap = ti.field(ti.f32, shape=n_tools)
        self.tool_max_gap = ti.field(ti.f32, shape=n_tools)
        self.tool_friction = ti.field(ti.f32, shape=n_tools)
        self.tool_lower = ti.Vector.field(3, ti.f32, shape=n_tools)
        self.tool_upper = ti.Vector.field(3, ti.f32, shape=n_tools)
        self.action_scale = ti.field(ti.f32, shape=max(self.action_dim, 1))
        self.health = ti.field(ti.f32, shape=2)  # [non-finite count, max speed]

    # ------------------------------------------------------------------ setup
    def set_material(self, material: MaterialConfig) -> None:
        """Set E, nu, yield stress, density and ground friction (Table 2)."""
        e, nu = material.youngs_modulus_pa, material.poisson_ratio
        self.mu[None] = e / (2 * (1 + nu))
        self.lam[None] = e * nu / ((1 + nu) * (1 - 2 * nu))
        self.yield_stress[None] = material.yield_stress_pa
        self.density[None] = material.density
        self.ground_friction[None] = material.ground_friction

    def set_gravity(self, gravity: Sequence[float]) -> None:
        """Effective gravitational acceleration, unit-cube lengths per s^2."""
        self.gravity[None] = [float(g) for g in gravity]

    def set_softness(self, softness: float) -> None:
        """Contact softness: 0 is hard contact (sdf <= 0); > 0 reaches out to sdf < ln(10)/softness."""
        if softness < 0:
            raise ValueError(f"contact softness must be >= 0, got {softness}")
        self.softness[None] = softness

    def set_expel_rates(self, rates: Sequence[float]) -> None:
        """Per tool, the fraction of its depth inside the tool that a grid node loses per substep
        (0: none, as official). One value per tool, in the compiled layout's order."""
        if len(rates) != len(self.tool_kinds):
            raise ValueError(f"expected {len(self.tool_kinds)} expel rates (one per tool), got {len(rates)}")
        for k, rate in enumerate(rates):
            if not 0.0 <= rate <= 1.0:
                raise ValueError(f"expel rate of tool {k} must be in [0, 1], got {rate}")
            self.tool_expel_rate[k] = rate

    def set_tools(self, tools: Sequence[ToolConfig]) -> None:
        """Set every tool's geometry, friction, bounds and action scales (runtime values)."""
        kinds = tuple(t.kind for t in tools)
        static = tuple(t.static for t in tools)
        if kinds != self.tool_kinds or static != self.static_tools:
            raise ValueError(f"tools {kinds} (static {static}) do not match the compiled layout "
                             f"{self.tool_kinds} (static {self.static_tools})")
        scales = np.zeros(max(self.action_dim, 1), dtype=np.float32)
        for k, tool in enumerate(tools):
            self.tool_half[k] = tool.half_extents
            self.tool_radius[k] = tool.radius
            self.tool_half_length[k] = tool.half_length
            self.tool_blade_depth[k] = tool.blade_depth
            self.tool_blade_slope[k] = 1.0 / math.tan(math.radians(tool.blade_angle_deg) / 2)
            self.tool_min_gap[k] = tool.min_gap
            self.tool_max_gap[k] = tool.max_gap
            self.tool_friction[k] = tool.friction
            self.tool_lower[k] = tool.lower_bound
            self.tool_upper[k] = tool.upper_bound
            if not tool.static:
                start = self.action_offsets[k]
                scales[start : start + ACTION_DIMS[tool.kind]] = tool.action_scales
        self.action_scale.from_numpy(scales)

    # ------------------------------------------------------------- constitutive
    @ti.func
    def plastic_singular_values(self, sig):
        """The return mapping on the singular values of the trial F (3, 3, diagonal): those of the
        post-plastic F (3,) and the deviatoric part of the trial Hencky strain (3,).

        The floored values' logarithms (Hencky strain) keep their mean and have their deviatoric part
        scaled down to the yield surface where it lies beyond it.
        """
        s = ti.max(ti.Vector([sig[0, 0], sig[1, 1], sig[2, 2]]), SINGULAR_VALUE_FLOOR)
        eps = ti.log(s)
        eps_dev = eps - eps.sum() / 3.0
        dev_norm = ti.sqrt(eps_dev.dot(eps_dev) + 1e-8)
        excess = ti.max(dev_norm - self.yield_stress[None] / (2.0 * self.mu[None]), 0.0)
        return ti.exp(eps - (excess / dev_norm) * eps_dev), eps_dev

    @ti.func
    def principal_stress(self, s_new):
        """The Kirchhoff stress's eigenvalues (3,) for the post-plastic singular values ``s_new`` (3,):
        ``2 mu (s^2 - s) + lam J (J - 1)``, the fixed-corotated model."""
        J = s_new[0] * s_new[1] * s_new[2]
        return 2.0 * self.mu[None] * (s_new * s_new - s_new) + self.lam[None] * J * (J - 1.0)

    @ti.func
    def affine_momentum(self, U, d, C):
        """The APIC affine momentum matrix (3, 3) of a particle with Kirchhoff stress ``U diag(d) U^T`` and
        affine velocity ``C`` (3, 3)."""
        stress = ti.Matrix.cols([U[:, i] * d[i] for i in ti.static(range(3))]) @ U.transpose()
        return (-self.dt * self.p_vol * 4.0 * self.inv_dx * self.inv_dx) * stress + self.particle_mass() * C

    @ti.func
    def constitutive_adjoint(self, rec: ti.template(), f, p, g_affine, U, V, s_new, d):
        """Hand-written adjoint of particle p's trial F, SVD and stress, given the adjoint of its affine
        matrix (3, 3) and of ``F[f + 1]``: sets the adjoints of ``C[f]`` and ``F[f]``.

        Works in the singular frames ``U``, ``V`` (3, 3) of substep f's trial F, where the stress
        ``U diag(d) U^T`` and the new F ``U diag(s_new) V^T`` are diagonal, from the return mapping that
        :meth:`fresh_affine` recorded in ``rec`` (``sig``, ``sig_plastic`` = ``s_new``, ``strain_dev``).
        """
        sig, eps_dev = self.recorded_vector(rec, f, p, "sig"), self.recorded_vector(rec, f, p, "strain_dev")
        mu, lam = self.mu[None], self.lam[None]
        s = ti.max(sig, SINGULAR_VALUE_FLOOR)
        dev_norm = ti.sqrt(eps_dev.dot(eps_dev) + 1e-8)
        yield_strain = self.yield_stress[None] / (2.0 * mu)
        J = s_new[0] * s_new[1] * s_new[2]

        g_stress = (-self.dt * self.p_vol * 4.0 * self.inv_dx * self.inv_dx) * g_affine
        Ut = U.transpose()
        Q = Ut @ (g_stress + g_stress.transpose()) @ U  # U^T (g + g^T) U, symmetric
        M = Ut @ self.F.grad[f + 1, p] @ V  # the new F's adjoint in the singular frames
        g_d = 0.5 * ti.Vector([Q[0, 0], Q[1, 1], Q[2, 2]])
        g_J = lam * (2.0 * J - 1.0) * g_d.sum()
        g_s_new = ti.Vector([M[0, 0], M[1, 1], M[2, 2]]) + 2.0 * mu * (2.0 * s_new - 1.0) * g_d + g_J * J / s_new
        # s_new = exp(eps'), eps' = eps - max(|dev| - yield, 0) / |dev| * dev (dev: deviatoric part of eps).
        g_eps_new = g_s_new * s_new
        g_eps = g_eps_new
        if dev_norm > yield_strain:
            # eps' = mean(eps) + yield * dev / |dev|: the mean passes through, the rest is projected.
            h = yield_strain * (g_eps_new / dev_norm - eps_dev * (eps_dev.dot(g_eps_new) / dev_norm**3))
            g_eps = g_eps_new.sum() / 3.0 + h - h.sum() / 3.0
        g_sig = ti.Vector([ti.select(sig[i] > SINGULAR_VALUE_FLOOR, g_eps[i] / s[i], 0.0)
                           for i in ti.static(range(3))])
        # U^T g_U = Q diag(d) + M diag(s_new) and V^T g_V = M^T diag(s_new).
        A = ti.Matrix([[Q[i, j] * d[j] + M[i, j] * s_new[j] for j in ti.static(range(3))]
                       for i in ti.static(range(3))])
        B = ti.Matrix([[M[j, i] * s_new[j] for j in ti.static(range(3))] for i in ti.static(range(3))])
        g_F_trial = U @ svd_adjoint_in_frame(sig, A - A.transpose(), B - B.transpose(), g_sig) @ V.transpose()
        # F_trial = (I + dt C) F; the affine matrix holds m C too.
        C, F = self.recorded_matrix(rec, f, p, "C"), self.recorded_matrix(rec, f, p, "F")
        self.C.grad[f, p] = self.dt * g_F_trial @ F.transpose() + self.particle_mass() * g_affine
        self.F.grad[f, p] = (ti.Matrix.identity(ti.f32, 3) + self.dt * C).transpose() @ g_F_trial

    # ------------------------------------------------------------------ kernels
    @ti.func
    def particle_mass(self):
        return self.p_vol * self.density[None]

    @ti.func
    def fresh_affine(self, f, p, record: ti.template(), out: ti.template()):
        """Trial F, SVD, return mapping and stress of particle p in one go: writes the post-plastic F to frame
        f + 1 and the APIC affine matrix (3, 3) to ``affine``.

        The affine matrix goes to frame f when differentiable, else to the single frame 0. With
        ``record``, particle p's state at frame f with its SVD and return mapping goes to ``out``
        (:meth:`write_record`), for the adjoint pass.
        """
        C, F = self.C[f, p], self.F[f, p]
        F_trial = (ti.Matrix.identity(ti.f32, 3) + self.dt * C) @ F
        U, sig, V = self.decompose(F_trial)
        s_new, eps_dev = self.plastic_singular_values(sig)
        self.F[f + 1, p] = ti.Matrix.cols([U[:, i] * s_new[i] for i in ti.static(range(3))]) @ V.transpose()
        affine = self.affine_momentum(U, self.principal_stress(s_new), C)
        if ti.static(record):
            self.write_record(out, f, p, self.x[f, p], self.v[f, p], C, F,
                              ti.Vector([sig[0, 0], sig[1, 1], sig[2, 2]]), s_new, eps_dev, U, V)
        if ti.static(self.differentiable):
            self.affine[f, p] = affine
        else:
            self.affine[0, p] = affine

    @ti.func
    def stencil(self, x):
        """The quadratic B-spline stencil of a particle at ``x`` (3,).

        Returns its lowest node ``base`` (3,) int, its position relative to that node in cells
        ``fx`` (3,) in [0.5, 1.5), and the weights ``w`` (3, 3): ``w[i, d]`` of offset i along axis d.
        """
        Xp = x * self.inv_dx
        base = ti.cast(Xp - 0.5, ti.i32)
        fx = Xp - ti.cast(base, ti.f32)
        return base, fx, bspline_weights(fx)

    @ti.func
    def scatter(self, c, f, p, affine):
        """Add particle p's mass and APIC momentum to chunk c's grid; return its stencil's lowest node (3,).

        A node at integer offset o gets ``weight (m v + affine (o - fx) dx)``, the bracket built up one axis
        at a time from the affine matrix's columns (adds instead of a 3x3 product per node).
        """
        base, fx, w = self.stencil(self.x[f, p])
        p_mass = self.particle_mass()
        columns = [affine[:, d] * self.dx for d in ti.static(range(3))]
        start = p_mass * self.v[f, p] - affine @ (fx * self.dx)
        for i in ti.static(range(3)):
            along_i = start
            if ti.static(i > 0):
                along_i = start + ti.static(float(i)) * columns[0]
            for j in ti.static(range(3)):
                along_ij = along_i
                if ti.static(j > 0):
                    along_ij = along_i + ti.static(float(j)) * columns[1]
                w_ij = w[i, 0] * w[j, 1]
                for k in ti.static(range(3)):
                    momentum = along_ij
                    if ti.static(k > 0):
                        momentum = along_ij + ti.static(float(k)) * columns[2]
                    weight = w_ij * w[k, 2]
                    added = weight * momentum
                    self.add_to_chunk(c, base + ti.Vector([i, j, k]),
                                      ti.Vector([added[0], added[1], added[2], weight * p_mass]))
        return base

    @ti.func
    def add_to_chunk(self, c, node, value):
        """``grid_part[c, node] += value`` (4,): a plain add when ordered (one thread per chunk), else atomic."""
        if ti.static(self.serial_p2g):
            self.grid_part[c, node] = self.grid_part[c, node] + value
        else:
            self.grid_part[c, node] += value

    @ti.func
    def chunk_bounds(self, c):
        """The particles of chunk c (ordered P2G): indices from ``c n / K`` up to ``(c + 1) n / K``, excluded."""
        return (c * self.n) // self.p2g_chunks, ((c + 1) * self.n) // self.p2g_chunks

    @ti.func
    def particles_to_chunks(self, f):
        """P2G of frame f's particles into the chunks' grids, with the affine matrices kept by
        :meth:`fresh_affine`, and each chunk's box of stencil nodes.

        Ordered (``layout.serial_p2g``): chunk c holds particles ``[c n / K, (c + 1) n / K)`` of the
        K = ``P2G_CHUNKS`` chunks and scatters them serially into its own grid, the chunks in parallel:
        bit-reproducible and free of float atomics. Otherwise one grid and atomic adds in a parallel
        loop over the particles (a GPU's only fast way).
        """
        kept = f if ti.static(self.differentiable) else 0
        if ti.static(self.serial_p2g):
            for c in range(self.p2g_chunks):
                lo = ti.Vector([self.n_grid] * 3)
                hi = ti.Vector([-1] * 3)
                begin, end = self.chunk_bounds(c)
                for p in range(begin, end):
                    base = self.scatter(c, f, p, self.affine[kept, p])
                    lo = ti.min(lo, base)
                    hi = ti.max(hi, base + 2)
                self.chunk_lo[c] = lo
                self.chunk_hi[c] = hi
        else:
            for p in range(self.n):
                self.scatter(0, f, p, self.affine[kept, p])

    @ti.func
    def find_active_box(self):
        """``active_lo``, ``active_hi``: the box of every stencil node (inclusive; the whole grid when atomic)."""
        lo = ti.Vector([0] * 3)
        hi = ti.Vector([self.n_grid - 1] * 3)
        if ti.static(self.serial_p2g):
            lo = ti.Vector([self.n_grid - 1] * 3)
            hi = ti.Vector([0] * 3)
            for c in ti.static(range(self.p2g_chunks)):
                lo = ti.min(lo, self.chunk_lo[c])
                hi = ti.max(hi, self.chunk_hi[c])
            lo = ti.max(lo, 0)
            hi = ti.min(hi, self.n_grid - 1)
        self.active_lo[None] = lo
        self.active_hi[None] = hi

    @ti.func
    def gather_chunks(self, cell):
        """The chunks' grids summed in chunk order at ``cell``: momentum (0:3) and mass (3); leaves them zero."""
        total = ti.Vector.zero(ti.f32, 4)
        for c in ti.static(range(self.p2g_chunks)):
            total += self.grid_part[c, cell]
            self.grid_part[c, cell] = ti.Vector.zero(ti.f32, 4)
        return total

    @ti.kernel
    def p2g_adjoint(self, f: ti.i32, rec: ti.types.ndarray(ndim=1)):
        """Hand-written adjoint of P2G and, per particle, of the stress before it: grid adjoints to x[f],
        v[f] and the affine matrix, and from it (:meth:`constitutive_adjoint`) to C[f] and F[f]. Sets the
        adjoints of v, C and F at frame f and adds to x's, which :meth:`g2p_adjoint` set. The affine
        matrix is rebuilt from the kept SVD and return mapping (a few products) rather than kept.

        A node's offset from the particle is ``(o - fx) dx`` for the node's integer offset ``o``, so the
        affine matrix's part of its momentum is built from the matrix's columns, and the sums over the
        27 nodes that a product with the affine matrix or ``fx`` would repeat are taken once (``g_momentum``
        and ``offset_sums``). Frame f's particles come from the recorded step ``rec``.
        """
        for p in range(self.n):
            base, fx, w = self.stencil(self.recorded_vector(rec, f, p, "x"))
            slope = bspline_slopes(fx)
            p_mass = self.particle_mass()
            U, V = self.recorded_matrix(rec, f, p, "U"), self.recorded_matrix(rec, f, p, "V")
            s_new = self.recorded_vector(rec, f, p, "sig_plastic")
            stress_values = self.principal_stress(s_new)
            affine = self.affine_momentum(U, stress_values, self.recorded_matrix(rec, f, p, "C"))
            columns = [affine[:, d] * self.dx for d in ti.static(range(3))]
            # momentum + affine @ ((o - fx) dx), accumulated one axis at a time over the offsets o.
            start = p_mass * self.recorded_vector(rec, f, p, "v") - affine @ (fx * self.dx)
            g_momentum = ti.Vector.zero(ti.f32, 3)
            offset_sums = [ti.Vector.zero(ti.f32, 3) for _ in ti.static(range(3))]  # sum of o_d w g_v
            g_x = ti.Vector.zero(ti.f32, 3)
            for i in ti.static(range(3)):
                along_i = start + ti.static(float(i)) * columns[0]
                for j in ti.static(range(3)):
                    along_ij = along_i + ti.static(float(j)) * columns[1]
                    for k in ti.static(range(3)):
                        contribution = along_ij + ti.static(float(k)) * columns[2]
                        node = base + ti.Vector([i, j, k])
                        weight, d_weight = node_weight_and_gradient(w, slope, i, j, k, self.inv_dx)
                        g_v = self.grid_v_in.grad[node]
                        weighted = weight * g_v
                        g_momentum += weighted
                        for d, o in ti.static(enumerate((i, j, k))):
                            if ti.static(o > 0):
                                offset_sums[d] += ti.static(float(o)) * weighted
                        g_x += (g_v.dot(contribution) + self.grid_m.grad[node] * p_mass) * d_weight
            g_affine = ti.Matrix.cols([(offset_sums[d] - fx[d] * g_momentum) * self.dx for d in ti.static(range(3))])
            self.v.grad[f, p] = p_mass * g_momentum
            self.x.grad[f, p] += g_x - affine.transpose() @ g_momentum
            self.constitutive_adjoint(rec, f, p, g_affine, U, V, s_new, stress_values)

    @ti.kernel
    def tool_kinematics(self, f: ti.i32):
        """Advance every tool's pose from frame f to f + 1 under the current action."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            self.move_tools(f)

    @ti.func
    def move_tools(self, f):
        for k in ti.static(range(self.n_tools)):
            if ti.static(self.static_tools[k]):
                self.tool_pos[f + 1, k] = self.tool_pos[f, k]
                self.tool_rot[f + 1, k] = self.tool_rot[f, k]
                self.tool_gap[f + 1, k] = self.tool_gap[f, k]
            else:
                self.advance_tool(f, k)

    @ti.func
    def advance_tool(self, f, k: ti.template()):
        a0 = ti.static(self.action_offsets[k])
        inv_sub = 1.0 / self.substeps
        pos = self.tool_pos[f, k]
        rot = self.tool_rot[f, k]
        gap = self.tool_gap[f, k]
        if ti.static(self.tool_kinds[k] == "knife"):
            pos += inv_sub * ti.Vector([self.scaled(a0 + d) for d in ti.static(range(3))])
        elif ti.static(self.tool_kinds[k] == "box"):
            pos += inv_sub * ti.Vector([self.scaled(a0 + d) for d in ti.static(range(3))])
            w = inv_sub * ti.Vector([self.scaled(a0 + 3 + d) for d in ti.static(range(3))])
            rot = quat_normalised(quat_mul(axis_angle_to_quat(w), rot))
        elif ti.static(self.tool_kinds[k] == "gripper"):
            pos += inv_sub * ti.Vector([self.scaled(a0 + d) for d in ti.static(range(3))])
            w = inv_sub * ti.Vector([self.scaled(a0 + 3 + d) for d in ti.static(range(3))])
            rot = quat_normalised(quat_mul(rot, axis_angle_to_quat(w)))
            gap = ti.min(ti.max(gap - inv_sub * self.scaled(a0 + 6), self.tool_min_gap[k]),
                         self.tool_max_gap[k])
        elif ti.static(self.tool_kinds[k] == "rolling_pin"):
            roll = inv_sub * self.scaled(a0)
            yaw = inv_sub * self.scaled(a0 + 1)
            lift = inv_sub * self.scaled(a0 + 2)
            slide = inv_sub * self.scaled(a0 + 3)
            axis = quat_to_matrix(rot) @ ti.Vector([0.0, 0.0, 1.0])
            direction = ti.Vector([0.0, 1.0, 0.0]).cross(axis)
            pos += direction * (roll * self.tool_radius[k] + slide) + ti.Vector([0.0, lift, 0.0])
            rot = quat_mul(axis_angle_to_quat(ti.Vector([0.0, -yaw, 0.0])), rot)
            rot = quat_normalised(quat_mul(rot, axis_angle_to_quat(ti.Vector([0.0, 0.0, roll]))))
        pos = ti.min(ti.max(pos, self.tool_lower[k]), self.tool_upper[k])
        for pair in ti.static(self.layout.collisions):
            if ti.static(pair[0] == k):
                pos = self.separate_from_obstacle(k, pair[1], pos, rot, gap)
        self.tool_pos[f + 1, k] = pos
        self.tool_rot[f + 1, k] = rot
        self.tool_gap[f + 1, k] = gap

    @ti.func
    def world_half_extents(self, k: ti.template(), rot, gap):
        """Half extents (3,) of the world-axis-aligned box around tool k at this rotation and gap."""
        local = ti.Vector.zero(ti.f32, 3)
        if ti.static(self.tool_kinds[k] == "box"):
            local = self.tool_half[k]
        elif ti.static(self.tool_kinds[k] == "gripper"):
            local = self.tool_half[k] + ti.Vector([0.5 * gap, 0.0, 0.0])
        elif ti.static(self.tool_kinds[k] == "rolling_pin"):
            r = self.tool_radius[k]
            local = ti.Vector([r, r, self.tool_half_length[k] + r])
        elif ti.static(self.tool_kinds[k] == "knife"):
            local = ti.Vector([self.tool_half[k][0], self.tool_half[k][1] + self.tool_blade_depth[k],
                               self.tool_half[k][2]])
        return ti.abs(quat_to_matrix(rot)) @ local

    @ti.func
    def separate_from_obstacle(self, k: ti.template(), j: ti.template(), pos, rot, gap):
        """Push tool k out of static box j along the axis of least overlap (bounding boxes).

        A simplification of the official projection of 600 board points: both tools are
        treated as world-axis-aligned boxes, which is exact for the unrotated spatula and board.
        """
        half_k = self.world_half_extents(k, rot, gap)
        half_j = ti.abs(quat_to_matrix(self.tool_rot[0, j])) @ self.tool_half[j]
        offset = pos - self.tool_pos[0, j]
        overlap = half_k + half_j - ti.abs(offset)
        least = ti.min(overlap[0], ti.min(overlap[1], overlap[2]))
        along_x = overlap[0] <= least
        along_y = (not along_x) and overlap[1] <= least
        direction = ti.select(along_x, ti.Vector([1.0, 0.0, 0.0]),
                              ti.select(along_y, ti.Vector([0.0, 1.0, 0.0]), ti.Vector([0.0, 0.0, 1.0])))
        push = direction * ti.select(offset.dot(direction) >= 0.0, 1.0, -1.0) * least
        penetrating = overlap[0] > 0.0 and overlap[1] > 0.0 and overlap[2] > 0.0
        return ti.select(penetrating, pos + push, pos)

    @ti.func
    def scaled(self, i: ti.template()):
        return ti.min(ti.max(self.action[i], -1.0), 1.0) * self.action_scale[i]

    @ti.func
    def local_sdf_normal(self, k: ti.template(), finger: ti.template(), p, gap):
        """SDF and outward normal of tool k (finger 0/1 for a gripper) at local point p."""
        sdf, normal = 0.0, ti.Vector([0.0, 1.0, 0.0])
        if ti.static(self.tool_kinds[k] == "box"):
            sdf, normal = box_sdf_normal(p, self.tool_half[k])
        elif ti.static(self.tool_kinds[k] == "knife"):
            sdf, normal = knife_sdf_normal(p, self.tool_half[k], self.tool_blade_depth[k], self.tool_blade_slope[k])
        elif ti.static(self.tool_kinds[k] == "rolling_pin"):
            sdf, normal = capsule_sdf_normal(p, self.tool_radius[k], self.tool_half_length[k])
        elif ti.static(self.tool_kinds[k] == "gripper"):
            sign = ti.static(1.0 if finger == 0 else -1.0)
            sdf, normal = box_sdf_normal(p - ti.Vector([sign * 0.5 * gap, 0.0, 0.0]), self.tool_half[k])
        return sdf, normal

    @ti.func
    def collide(self, f, k: ti.template(), finger: ti.template(), node, v):
        """Project the grid velocity ``v`` at world point ``node`` against tool k."""
        R0 = quat_to_matrix(self.tool_rot[f, k])
        local = R0.transpose() @ (node - self.tool_pos[f, k])
        gap0 = self.tool_gap[f, k]
        sdf, normal_local = self.local_sdf_normal(k, finger, local, gap0)
        softness = self.softness[None]
        influence = ti.min(ti.exp(-sdf * softness), 1.0)
        in_contact = sdf <= 0.0 or (softness > 0.0 and influence > SOFT_CONTACT_CUTOFF)
        result = v
        # A branch, not a select: the adjoint pass then skips the tool's terms at nodes out of contact.
        if in_contact:
            normal = R0 @ normal_local
            # Rigid velocity of the tool's material point at this node, including the gap motion.
            finger_shift0 = ti.Vector.zero(ti.f32, 3)
            finger_shift1 = ti.Vector.zero(ti.f32, 3)
            if ti.static(self.tool_kinds[k] == "gripper"):
                sign = ti.static(1.0 if finger == 0 else -1.0)
                finger_shift0 = ti.Vector([sign * 0.5 * gap0, 0.0, 0.0])
                finger_shift1 = ti.Vector([sign * 0.5 * self.tool_gap[f + 1, k], 0.0, 0.0])
            R1 = quat_to_matrix(self.tool_rot[f + 1, k])
            moved = self.tool_pos[f + 1, k] + R1 @ (local - finger_shift0 + finger_shift1)
            v_tool = (moved - node) / self.dt
            rel = v - v_tool
            normal_speed = rel.dot(normal)
            # Nodes inside the tool leave it at a speed that removes a fraction of their depth per substep.
            expel = self.tool_expel_rate[k] * ti.max(-sdf, 0.0) / self.dt
            removed = ti.min(normal_speed - expel, 0.0)
            tangential = rel - normal_speed * normal
            t_norm = ti.sqrt(tangential.dot(tangential) + 1e-20)
            with_friction = tangential / t_norm * ti.max(0.0, t_norm + removed * self.tool_friction[k])
            tangential = ti.select(removed < 0.0, with_friction, tangential) + ti.max(normal_speed, expel) * normal
            result = v_tool + rel * (1.0 - influence) + tangential * influence
        return result

    @ti.func
    def node_velocity(self, f, cell, m, momentum):
        """Velocity (3,) after the substep of a grid node with mass ``m`` > 0 and ``momentum`` (3,): gravity,
        the tools, the ground and the walls."""
        v = momentum / m + self.dt * self.gravity[None]
        node = ti.cast(cell, ti.f32) * self.dx
        for k in ti.static(range(self.n_tools)):
            v = self.collide(f, k, 0, node, v)
            if ti.static(self.tool_kinds[k] == "gripper"):
                v = self.collide(f, k, 1, node, v)
        bound = self.boundary_cells
        mu_g = self.ground_friction[None]
        t_norm = ti.sqrt(v[0] * v[0] + v[2] * v[2] + 1e-20)
        scale = ti.select(mu_g >= 10.0, 0.0, ti.max(1.0 + mu_g * v[1] / t_norm, 0.0))
        on_ground = cell[1] < bound and v[1] < 0.0
        v = ti.select(on_ground, ti.Vector([v[0] * scale, 0.0, v[2] * scale]), v)
        for d in ti.static(range(3)):
            outward_low = cell[d] < bound and v[d] < 0.0
            outward_high = cell[d] > self.n_grid - bound and v[d] > 0.0
            v[d] = ti.select(outward_low or outward_high, 0.0, v[d])
        return v

    @ti.kernel
    def grid_op(self, f: ti.i32):
        """The grid update on the active box, from ``grid_m`` and ``grid_v_in`` (as :meth:`g2p_adjoint` restores
        them): the primal of Taichi's adjoint ``grid_op.grad`` in :meth:`substep_grad`."""
        # The box's bounds are read in the loop statement: Taichi's autodiff refuses statements before a loop.
        lo, hi = ti.static(self.active_lo, self.active_hi)
        for cell in ti.grouped(ti.ndrange(*[(lo[None][d], hi[None][d] + 1) for d in range(3)])):
            m = self.grid_m[cell]
            if m > 1e-12:
                self.grid_v_out[cell] = self.node_velocity(f, cell, m, self.grid_v_in[cell])

    @ti.func
    def grid_to_particle(self, f, p):
        """G2P of particle p: its velocity, affine velocity C and position at frame f + 1.

        ``C = 4 / dx^2 sum_o w g_v (o - fx)^T dx`` is summed as ``sum_o w g_v o_d`` per axis d (adds, no
        outer product per node) less ``v fx_d``.
        """
        base, fx, w = self.stencil(self.x[f, p])
        new_v = ti.Vector.zero(ti.f32, 3)
        offset_sums = [ti.Vector.zero(ti.f32, 3) for _ in ti.static(range(3))]  # sum of o_d w g_v
        for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
            weighted = (w[i, 0] * w[j, 1] * w[k, 2]) * self.grid_v_out[base + ti.Vector([i, j, k])]
            new_v += weighted
            for d, o in ti.static(enumerate((i, j, k))):
                if ti.static(o == 1):
                    offset_sums[d] += weighted
                elif ti.static(o == 2):
                    offset_sums[d] += 2.0 * weighted
        scale = 4.0 * self.inv_dx
        self.v[f + 1, p] = new_v
        self.C[f + 1, p] = ti.Matrix.cols([scale * (offset_sums[d] - fx[d] * new_v) for d in ti.static(range(3))])
        self.x[f + 1, p] = ti.min(ti.max(self.x[f, p] + self.dt * new_v, self.x_low), self.x_high)

    @ti.kernel
    def advance(self, f: ti.i32, record: ti.template(), particles: ti.types.ndarray(ndim=1),
                grid: ti.types.ndarray(ndim=2), boxes: ti.types.ndarray(ndim=3)):
        """One substep from frame f to f + 1 in one kernel: trial F, SVD and stress per particle, the ordered
        P2G, the tools, the sum of the chunks' grids and their clearing fused into the grid update, then G2P.

        Only the box of the particles' stencil nodes is visited; ``grid_v_out`` elsewhere is left as it
        was (G2P reads none of it). With ``record``, what the adjoint of the substep needs goes straight to
        :meth:`record_step`'s arrays: each particle's state, SVD and return mapping at frame f to
        ``particles`` (:meth:`write_record`), the box to ``boxes[f]`` and its nodes' mass, momentum and new
        velocity to ``grid[f]`` (GRID_CHANNELS per node, the box's nodes in C order).
        """
        for p in range(self.n):
            self.fresh_affine(f, p, record, particles)
        self.particles_to_chunks(f)
        # Serial, on the launching thread: a parallel task costs a thread pool wake-up (40-90 us here).
        self.move_tools(f)
        self.find_active_box()
        if ti.static(record):
            for d in ti.static(range(3)):
                boxes[f, 0, d] = self.active_lo[None][d]
                boxes[f, 1, d] = self.active_hi[None][d]
        lo, hi = ti.static(self.active_lo, self.active_hi)
        for cell in ti.grouped(ti.ndrange(*[(lo[None][d], hi[None][d] + 1) for d in range(3)])):
            node = self.gather_chunks(cell)
            v = ti.Vector.zero(ti.f32, 3)
            if node[3] > 1e-12:
                v = self.node_velocity(f, cell, node[3], ti.Vector([node[0], node[1], node[2]]))
            self.grid_v_out[cell] = v
            if ti.static(record):
                start = GRID_CHANNELS * self.box_index(cell)
                for a in ti.static(range(4)):
                    grid[f, start + a] = node[(a + 3) % 4]  # mass, then momentum
                for a in ti.static(range(3)):
                    grid[f, start + 4 + a] = v[a]
        for p in range(self.n):
            self.grid_to_particle(f, p)

    @ti.func
    def particle_g2p_adjoint(self, rec: ti.template(), grid: ti.template(), c, f, p):
        """Adjoint of G2P for particle p: its share of grid_v_out's adjoint into chunk c's grid; sets x[f]'s.

        ``g_C @ (o - fx)`` is built from ``g_C``'s columns over the integer offsets o, and the term that
        G2P's ``(o - fx)`` adds to x's adjoint is summed over the nodes once: the weighted sum of the
        grid velocities is the new velocity ``v[f + 1]``. The particle's states and the grid velocities come
        from the recorded step (``rec``: its particles, ``grid``: its grids).
        """
        x = self.recorded_vector(rec, f, p, "x")
        base, fx, w = self.stencil(x)
        size = self.active_hi[None] - self.active_lo[None] + 1
        base_index = GRID_CHANNELS * self.box_index(base)
        slope = bspline_slopes(fx)
        new_v = self.recorded_vector(rec, f + 1, p, "v")
        moved = x + self.dt * new_v
        free = ti.Vector([ti.select(self.x_low < moved[d] < self.x_high, 1.0, 0.0) for d in ti.static(range(3))])
        g_x_next = self.x.grad[f + 1, p] * free
        g_v = self.v.grad[f + 1, p] + self.dt * g_x_next
        scale = 4.0 * self.inv_dx
        g_C = scale * self.C.grad[f + 1, p]
        columns = [g_C[:, d] for d in ti.static(range(3))]
        # The adjoint a node's velocity gets per unit weight: g_v + scale g_C (o - fx).
        start = g_v - g_C @ fx
        g_x = g_x_next - self.inv_dx * (g_C.transpose() @ new_v)
        for i in ti.static(range(3)):
            along_i = start + ti.static(float(i)) * columns[0]
            for j in ti.static(range(3)):
                along_ij = along_i + ti.static(float(j)) * columns[1]
                for k in ti.static(range(3)):
                    per_weight = along_ij + ti.static(float(k)) * columns[2]
                    node = base + ti.Vector([i, j, k])
                    weight, d_weight = node_weight_and_gradient(w, slope, i, j, k, self.inv_dx)
                    g_node = weight * per_weight
                    self.add_to_chunk(c, node, ti.Vector([g_node[0], g_node[1], g_node[2], 0.0]))
                    slot = base_index + GRID_CHANNELS * ((i * size[1] + j) * size[2] + k) + 4
                    new_node_v = ti.Vector([grid[f, slot + a] for a in ti.static(range(3))])
                    g_x += new_node_v.dot(per_weight) * d_weight
        self.x.grad[f, p] = g_x

    @ti.kernel
    def g2p_adjoint(self, f: ti.i32, rec: ti.types.ndarray(ndim=1), grid: ti.types.ndarray(ndim=2),
                    boxes: ti.types.ndarray(ndim=3)):
        """Hand-written adjoint of G2P: adjoints of x, v, C at f + 1 to grid_v_out and x at f; and the grid
        update's input restored for its adjoint.

        Reads substep f of a recorded step: its particles (``rec``), grids (``grid``) and box (``boxes``),
        as :meth:`advance` recorded them. The grid adjoints go through the chunks' grids like P2G's mass
        and momentum (a fixed summation order when ordered) and are summed into ``grid_v_out.grad`` on the
        box, where ``grid_m`` and ``grid_v_in`` are restored and their adjoints zeroed for ``grid_op.grad``.
        """
        for d in ti.static(range(3)):
            self.active_lo[None][d] = boxes[f, 0, d]
            self.active_hi[None][d] = boxes[f, 1, d]
        if ti.static(self.serial_p2g):
            for c in range(self.p2g_chunks):
                begin, end = self.chunk_bounds(c)
                for p in range(begin, end):
                    self.particle_g2p_adjoint(rec, grid, c, f, p)
        else:
            for p in range(self.n):
                self.particle_g2p_adjoint(rec, grid, 0, f, p)
        lo, hi = ti.static(self.active_lo, self.active_hi)
        for cell in ti.grouped(ti.ndrange(*[(lo[None][d], hi[None][d] + 1) for d in range(3)])):
            total = self.gather_chunks(cell)
            self.grid_v_out.grad[cell] = ti.Vector([total[0], total[1], total[2]])
            start = GRID_CHANNELS * self.box_index(cell)
            self.grid_m[cell] = grid[f, start]
            self.grid_v_in[cell] = ti.Vector([grid[f, start + 1 + a] for a in ti.static(range(3))])
            self.grid_m.grad[cell] = 0.0
            self.grid_v_in.grad[cell] = ti.Vector.zero(ti.f32, 3)

    @ti.kernel
    def copy_frame(self, src: ti.i32, dst: ti.i32):
        for p in range(self.n):
            self.x[dst, p] = self.x[src, p]
            self.v[dst, p] = self.v[src, p]
            self.C[dst, p] = self.C[src, p]
            self.F[dst, p] = self.F[src, p]
        for k in range(self.n_tools):
            self.tool_pos[dst, k] = self.tool_pos[src, k]
            self.tool_rot[dst, k] = self.tool_rot[src, k]
            self.tool_gap[dst, k] = self.tool_gap[src, k]

    @ti.kernel
    def measure_health(self, f: ti.i32):
        """health[0]: sum of |x|, |v|, |F| (non-finite if any value is); health[1]: max speed."""
        self.health[0] = 0.0
        self.health[1] = 0.0
        for p in range(self.n):
            speed2 = self.v[f, p].dot(self.v[f, p])
            ti.atomic_add(self.health[0], ti.abs(self.x[f, p]).sum() + speed2 + ti.abs(self.F[f, p]).sum())
            ti.atomic_max(self.health[1], ti.sqrt(speed2))

    # ------------------------------------------------------------ state in/out
    @ti.kernel
    def _write_frame(self, f: ti.i32, x: ti.types.ndarray(), v: ti.types.ndarray(), C: ti.types.ndarray(),
                     F: ti.types.ndarray()):
        for p in range(self.n):
            for a in ti.static(range(3)):
                self.x[f, p][a] = x[p, a]
                self.v[f, p][a] = v[p, a]
                for b in ti.static(range(3)):
                    self.C[f, p][a, b] = C[p, a, b]
                    self.F[f, p][a, b] = F[p, a, b]

    @ti.kernel
    def _read_frame(self, f: ti.i32, x: ti.types.ndarray(), v: ti.types.ndarray(), C: ti.types.ndarray(),
                    F: ti.types.ndarray()):
        for p in range(self.n):
            for a in ti.static(range(3)):
                x[p, a] = self.x[f, p][a]
                v[p, a] = self.v[f, p][a]
                for b in ti.static(range(3)):
                    C[p, a, b] = self.C[f, p][a, b]
                    F[p, a, b] = self.F[f, p][a, b]

    @ti.kernel
    def _write_tools(self, f: ti.i32, pos: ti.types.ndarray(), rot: ti.types.ndarray(), gap: ti.types.ndarray()):
        for k in range(self.n_tools):
            for a in ti.static(range(3)):
                self.tool_pos[f, k][a] = pos[k, a]
            for a in ti.static(range(4)):
                self.tool_rot[f, k][a] = rot[k, a]
            self.tool_gap[f, k] = gap[k]

    @ti.kernel
    def _copy_tools(self, tools: ti.types.ndarray(ndim=3), to_fields: ti.template()):
        """Every frame's tool poses between the fields and ``tools`` (frames, K, 8): position, rotation
        quaternion, gap; into the fields with ``to_fields``, else out of them."""
        ti.loop_config(serialize=True)  # a few dozen values: cheaper than waking the thread pool
        for f, k in ti.ndrange(self.n_frames, self.n_tools):
            if ti.static(to_fields):
                self.tool_pos[f, k] = ti.Vector([tools[f, k, a] for a in ti.static(range(3))])
                self.tool_rot[f, k] = ti.Vector([tools[f, k, 3 + a] for a in ti.static(range(4))])
                self.tool_gap[f, k] = tools[f, k, 7]
            else:
                pos, rot = self.tool_pos[f, k], self.tool_rot[f, k]
                for a in ti.static(range(3)):
                    tools[f, k, a] = pos[a]
                for a in ti.static(range(4)):
                    tools[f, k, 3 + a] = rot[a]
                tools[f, k, 7] = self.tool_gap[f, k]

    @ti.kernel
    def _read_tools(self, f: ti.i32, pos: ti.types.ndarray(), rot: ti.types.ndarray(), gap: ti.types.ndarray()):
        for k in range(self.n_tools):
            for a in ti.static(range(3)):
                pos[k, a] = self.tool_pos[f, k][a]
            for a in ti.static(range(4)):
                rot[k, a] = self.tool_rot[f, k][a]
            gap[k] = self.tool_gap[f, k]

    @ti.kernel
    def clear_tool_grads(self):
        """Zero the adjoints of the tools and the action, which the grid update's adjoint accumulates. The
        particles' need no clearing: each substep's adjoint sets those of its first frame."""
        ti.loop_config(serialize=True)
        for f, k in self.tool_pos:
            self.tool_pos.grad[f, k] = ti.Vector.zero(ti.f32, 3)
            self.tool_rot.grad[f, k] = ti.Vector.zero(ti.f32, 4)
            self.tool_gap.grad[f, k] = 0.0
        ti.loop_config(serialize=True)
        for i in self.action:
            self.action.grad[i] = 0.0

    @ti.kernel
    def _set_frame_grad(self, f: ti.i32, x: ti.types.ndarray(), v: ti.types.ndarray(), C: ti.types.ndarray(),
                        F: ti.types.ndarray()):
        for p in range(self.n):
            for a in ti.static(range(3)):
                self.x.grad[f, p][a] = x[p, a]
                self.v.grad[f, p][a] = v[p, a]
                for b in ti.static(range(3)):
                    self.C.grad[f, p][a, b] = C[p, a, b]
                    self.F.grad[f, p][a, b] = F[p, a, b]

    @ti.kernel
    def _read_frame_grad(self, f: ti.i32, x: ti.types.ndarray(), v: ti.types.ndarray(), C: ti.types.ndarray(),
                         F: ti.types.ndarray()):
        for p in range(self.n):
            for a in ti.static(range(3)):
                x[p, a] = self.x.grad[f, p][a]
                v[p, a] = self.v.grad[f, p][a]
                for b in ti.static(range(3)):
                    C[p, a, b] = self.C.grad[f, p][a, b]
                    F[p, a, b] = self.F.grad[f, p][a, b]

    @ti.kernel
    def _add_tools_grad(self, f: ti.i32, pos: ti.types.ndarray(), rot: ti.types.ndarray(),
                        gap: ti.types.ndarray()):
        for k in range(self.n_tools):
            for a in ti.static(range(3)):
                self.tool_pos.grad[f, k][a] += pos[k, a]
            for a in ti.static(range(4)):
                self.tool_rot.grad[f, k][a] += rot[k, a]
            self.tool_gap.grad[f, k] += gap[k]

    @ti.kernel
    def _read_tools_grad(self, f: ti.i32, pos: ti.types.ndarray(), rot: ti.types.ndarray(),
                         gap: ti.types.ndarray()):
        for k in range(self.n_tools):
            for a in ti.static(range(3)):
                pos[k, a] = self.tool_pos.grad[f, k][a]
            for a in ti.static(range(4)):
                rot[k, a] = self.tool_rot.grad[f, k][a]
            gap[k] = self.tool_gap.grad[f, k]

    def seed_state_grad(self, grad: dict[str, np.ndarray], frame: int) -> None:
        """Set a frame's particle adjoints and add to its tools' (keys as in :meth:`get_state`; missing keys
        are zero), after :meth:`clear_tool_grads`: the last frame's, where a step's adjoint starts."""
        n, k = self.n, max(self.n_tools, 1)

        def arr(key, shape):
            value = grad.get(key)
            return np.zeros(shape, np.float32) if value is None else np.ascontiguousarray(value, np.float32)

        self._set_frame_grad(frame, arr("x", (n, 3)), arr("v", (n, 3)), arr("C", (n, 3, 3)), arr("F", (n, 3, 3)))
        if self.n_tools:
            self._add_tools_grad(frame, arr("tool_pos", (k, 3)), arr("tool_rot", (k, 4)), arr("tool_gap", (k,)))

    def read_state_grad(self, frame: int) -> dict[str, np.ndarray]:
        """Adjoints of a frame's state, keys as in :meth:`get_state`."""
        n, k = self.n, max(self.n_tools, 1)
        out = {"x": np.empty((n, 3), np.float32), "v": np.empty((n, 3), np.float32),
               "C": np.empty((n, 3, 3), np.float32), "F": np.empty((n, 3, 3), np.float32)}
        self._read_frame_grad(frame, out["x"], out["v"], out["C"], out["F"])
        pos, rot, gap = np.zeros((k, 3), np.float32), np.zeros((k, 4), np.float32), np.zeros(k, np.float32)
        if self.n_tools:
            self._read_tools_grad(frame, pos, rot, gap)
        out.update(tool_pos=pos[: self.n_tools], tool_rot=rot[: self.n_tools], tool_gap=gap[: self.n_tools])
        return out

    def read_action_grad(self) -> np.ndarray:
        return self.action.grad.to_numpy()[: self.action_dim].copy()

    def read_particles(self, frame: int = 0) -> dict[str, np.ndarray]:
        """Particle state of one frame: x, v (N, 3) and C, F (N, 3, 3), float32 copies."""
        x = np.empty((self.n, 3), np.float32)
        v = np.empty((self.n, 3), np.float32)
        C = np.empty((self.n, 3, 3), np.float32)
        F = np.empty((self.n, 3, 3), np.float32)
        self._read_frame(frame, x, v, C, F)
        return {"x": x, "v": v, "C": C, "F": F}

    def read_tools(self, frame: int = 0) -> dict[str, np.ndarray]:
        """Tool poses of one frame: pos (K, 3), rot (K, 4) quaternions w-first, gap (K,)."""
        k = max(self.n_tools, 1)
        pos = np.zeros((k, 3), np.float32)
        rot = np.zeros((k, 4), np.float32)
        gap = np.zeros(k, np.float32)
        self._read_tools(frame, pos, rot, gap)
        return {"pos": pos[: self.n_tools], "rot": rot[: self.n_tools], "gap": gap[: self.n_tools]}

    def get_state(self) -> dict[str, np.ndarray]:
        """Everything needed to resume from here (frame 0): particles and tool poses."""
        state = self.read_particles(0)
        state.update({f"tool_{key}": value for key, value in self.read_tools(0).items()})
        return state

    def set_state(self, state: dict[str, np.ndarray], frame: int = 0) -> None:
        """Load a state from :meth:`get_state` (F and C default to identity and zero)."""
        x = np.ascontiguousarray(state["x"], dtype=np.float32)
        if x.shape != (self.n, 3):
            raise ValueError(f"state x has shape {x.shape}, this simulator holds ({self.n}, 3)")
        if not np.isfinite(x).all():
            raise ValueError("state x holds non-finite positions")
        v = np.ascontiguousarray(state.get("v", np.zeros_like(x)), dtype=np.float32)
        C = np.ascontiguousarray(state.get("C", np.zeros((self.n, 3, 3))), dtype=np.float32)
        F = np.ascontiguousarray(state.get("F", np.broadcast_to(np.eye(3), (self.n, 3, 3))), dtype=np.float32)
        self._write_frame(frame, x, v, C, F)
        if self.n_tools:
            pos = np.ascontiguousarray(state["tool_pos"], dtype=np.float32).reshape(self.n_tools, 3)
            rot = np.array(state["tool_rot"], dtype=np.float32).reshape(self.n_tools, 4)
            norms = np.linalg.norm(rot.astype(np.float64), axis=1)
            off_unit = np.abs(norms - 1.0) > 1e-6  # renormalise only what is not already unit (exact round trips)
            rot[off_unit] = (rot[off_unit] / norms[off_unit, None]).astype(np.float32)
            gap = np.ascontiguousarray(state["tool_gap"], dtype=np.float32).reshape(self.n_tools)
            self._write_tools(frame, pos, rot, gap)

    # -------------------------------------------------------------- stepping
    def check_action(self, action: np.ndarray, step: int | None = None) -> np.ndarray:
        """Validate an action: shape (A,), finite, within [-1, 1]; returns it as float32."""
        where = "" if step is None else f" at step {step}"
        a = np.asarray(action, dtype=np.float32).reshape(-1)
        if a.shape != (self.action_dim,):
            raise ActionError(f"action{where} has {a.size} values, expected {self.action_dim}")
        bad = ~np.isfinite(a) | (np.abs(a) > 1.0 + 1e-6)
        if bad.any():
            i = int(np.argmax(bad))
            raise ActionError(f"action{where} has value {a[i]!r} at index {i}; actions must be finite and in [-1, 1]")
        return a

    def load_action(self, action: np.ndarray) -> None:
        padded = np.zeros(max(self.action_dim, 1), np.float32)
        padded[: self.action_dim] = action
        self.action.from_numpy(padded)

    def substep_grad(self, f: int) -> None:
        """Adjoint of substep f of the step that :meth:`load_recorded_step` restored.

        Runs the adjoints in reverse order: G2P (which restores the grid update's input), the grid update,
        the tools, and P2G with the stress, the SVD and the trial F in one kernel (:meth:`p2g_adjoint`).
        """
        if self._loaded_step is None:
            raise RuntimeError("substep_grad needs the frames of a recorded step: call load_recorded_step first")
        recorded = self._loaded_step
        particles = recorded["particles"].reshape(-1)
        self.g2p_adjoint(f, particles, recorded["grid"], recorded["grid_boxes"])
        self.grid_op.grad(f)
        self.tool_kinematics.grad(f)
        self.p2g_adjoint(f, particles)

    def run_substeps(self, action: np.ndarray, step: int | None = None) -> None:
        """Run one environment step into frames 1..substeps without wrapping back to frame 0."""
        self._loaded_step = None  # the frames no longer hold a loaded recorded step
        self.load_action(self.check_action(action, step))
        for f in range(self.substeps):
            self.advance(f, False, *self._no_record)
        self.raise_if_unhealthy(self.substeps, step)

    def record_step(self, action: np.ndarray, step: int | None = None) -> dict[str, np.ndarray]:
        """Run one environment step and return all that its adjoint needs, for :meth:`load_recorded_step`:
        particles (frames, N, RECORD_CHANNELS), each substep's grid on its box (``grid``: (substeps,
        n_grid^3 * 7) of which the box's nodes fill the start, ``grid_boxes``: (substeps, 2, 3) lowest and
        highest node) and ``tools`` (frames, K, 8): position, rotation quaternion and gap. The substeps
        write them as they go (:meth:`advance` with ``record``).

        The arrays come from the buffers given back by :meth:`release_recorded_step` when there are any
        (a fresh one costs a page fault per 4 KiB on first write; the grid's untouched pages cost nothing).
        """
        if not self.differentiable:
            raise RuntimeError("record_step needs a simulator built with differentiable=True")
        if self._spare_records:
            recorded = self._spare_records.pop()
        else:
            recorded = {"particles": np.empty((self.n_frames, self.n, RECORD_CHANNELS), np.float32),
                        "grid": np.empty((self.substeps, self.n_grid**3 * GRID_CHANNELS), np.float32),
                        "grid_boxes": np.empty((self.substeps, 2, 3), np.int32),
                        "tools": np.empty((self.n_frames, max(self.n_tools, 1), 8), np.float32)}
        self._loaded_step = None
        self.load_action(self.check_action(action, step))
        particles = recorded["particles"].reshape(-1)
        for f in range(self.substeps):
            self.advance(f, True, particles, recorded["grid"], recorded["grid_boxes"])
        self.raise_if_unhealthy(self.substeps, step)
        self._record_last_frame(particles)
        self._copy_tools(recorded["tools"], False)
        return recorded

    def recorded_bytes(self, recorded: dict[str, np.ndarray]) -> int:
        """Memory in use by a :meth:`record_step`: the particles and the grid boxes' nodes."""
        sizes = recorded["grid_boxes"][:, 1] - recorded["grid_boxes"][:, 0] + 1
        return recorded["particles"].nbytes + 4 * GRID_CHANNELS * int(np.prod(sizes, axis=1).sum())

    def release_recorded_step(self, recorded: dict[str, np.ndarray]) -> None:
        """Give a recorded step's buffers back for reuse; ``recorded`` must not be used afterwards."""
        if self._loaded_step is recorded:
            self._loaded_step = None
        self._spare_records.append(recorded)

    def load_recorded_step(self, recorded: dict[str, np.ndarray]) -> None:
        """Make :meth:`record_step`'s step the one :meth:`substep_grad` differentiates: restore its tool poses;
        the adjoint kernels read its particles, and restore its substeps' grids, from ``recorded`` until
        :meth:`release_recorded_step`."""
        self._copy_tools(recorded["tools"], True)
        self._loaded_step = recorded

    @ti.func
    def box_index(self, cell):
        """The position of ``cell`` (3,) among the active box's nodes, in C order."""
        rel = cell - self.active_lo[None]
        size = self.active_hi[None] - self.active_lo[None] + 1
        return (rel[0] * size[1] + rel[1]) * size[2] + rel[2]

    @ti.func
    def write_record(self, out: ti.template(), f, p, x, v, C, F, sig, s_new, eps_dev, U, V):
        """Particle p's slot of frame f in ``out``, a flat (frames * N * RECORD_CHANNELS,) view of a recorded
        step's particles (indexed about 3x faster than a 3-d array), laid out as ``RECORD_LAYOUT``."""
        start = (f * self.n + p) * RECORD_CHANNELS
        for key, value in ti.static((("x", x), ("v", v), ("sig", sig), ("sig_plastic", s_new),
                                     ("strain_dev", eps_dev))):
            for a in ti.static(range(3)):
                out[start + ti.static(RECORD_LAYOUT[key]) + a] = value[a]
        for key, value in ti.static((("C", C), ("F", F), ("U", U), ("V", V))):
            for a, b in ti.static(ti.ndrange(3, 3)):
                out[start + ti.static(RECORD_LAYOUT[key]) + 3 * a + b] = value[a, b]

    @ti.func
    def recorded_vector(self, rec: ti.template(), f, p, key: ti.template()):
        """Quantity ``key`` (3,) of particle p at frame f in a recorded step (:meth:`write_record`)."""
        start = (f * self.n + p) * RECORD_CHANNELS + ti.static(RECORD_LAYOUT[key])
        return ti.Vector([rec[start + a] for a in ti.static(range(3))])

    @ti.func
    def recorded_matrix(self, rec: ti.template(), f, p, key: ti.template()):
        """Quantity ``key`` (3, 3) of particle p at frame f in a recorded step (:meth:`write_record`)."""
        start = (f * self.n + p) * RECORD_CHANNELS + ti.static(RECORD_LAYOUT[key])
        return ti.Matrix([[rec[start + 3 * a + b] for b in ti.static(range(3))] for a in ti.static(range(3))])

    @ti.kernel
    def _record_last_frame(self, out: ti.types.ndarray(ndim=1)):
        """The step's last frame's particles into ``out`` (:meth:`write_record`), zero SVD and return
        mapping: no substep starts from that frame."""
        f = self.substeps
        for p in range(self.n):
            zero, none = ti.Vector.zero(ti.f32, 3), ti.Matrix.zero(ti.f32, 3, 3)
            self.write_record(out, f, p, self.x[f, p], self.v[f, p], self.C[f, p], self.F[f, p],
                              zero, zero, zero, none, none)

    def step(self, action: np.ndarray, step: int | None = None) -> None:
        """Advance one environment step under ``action`` (A,) in [-1, 1]."""
        self.run_substeps(action, step)
        self.copy_frame(self.substeps, 0)

    def raise_if_unhealthy(self, frame: int, step: int | None) -> None:
        self.measure_health(frame)
        total, speed = (float(value) for value in self.health.to_numpy())
        where = "" if step is None else f" at step {step}"
        if not math.isfinite(total):
            raise SimulationError(f"simulation blew up{where}: particle state holds non-finite values ({total})")
        if not math.isfinite(speed) or speed > MAX_SPEED:
            raise SimulationError(f"simulation blew up{where}: particle speed {speed:.3g} exceeds {MAX_SPEED:g}")


_SIMULATORS: dict[tuple, MPMSimulator] = {}


def collision_pairs(tools: Sequence[ToolConfig]) -> tuple[tuple[int, int], ...]:
    """(moving tool, static box obstacle) index pairs from each tool's ``collides_with``."""
    index = {t.name: i for i, t in enumerate(tools)}
    pairs = []
    for i, tool in enumerate(tools):
        for name in tool.collides_with:
            j = index[name]
            if not (tools[j].static and tools[j].kind == "box"):
                raise ValueError(f"tool {tool.name!r} collides with {name!r}, which must be a static box")
            pairs.append((i, j))
    return tuple(pairs)


def expel_rates(sim: SimConfig, tools: Sequence[ToolConfig]) -> tuple[float, ...]:
    """Each tool's expel rate: its own ``expel_rate``, else the simulator's ``tool_expel_rate``."""
    return tuple(sim.tool_expel_rate if t.expel_rate is None else t.expel_rate for t in tools)


def simulator_for(sim: SimConfig, tools: Sequence[ToolConfig], n_particles: int | None = None,
                  differentiable: bool = False) -> MPMSimulator:
    """A simulator for this layout, shared within the process.

    Taichi compiles kernels per simulator object, so simulators are cached by
    their compile-time layout; runtime values (material, tools) are set by the
    caller every time.
    """
    arch = ensure_taichi(sim.arch)  # refuses an architecture other than the one this process already runs
    layout = SimLayout(
        n_grid=sim.n_grid,
        n_particles=n_particles or sim.n_particles,
        dt_s=sim.dt_s,
        substeps=sim.substeps_per_step,
        tool_kinds=tuple(t.kind for t in tools),
        differentiable=differentiable,
        collisions=collision_pairs(tools),
        static_tools=tuple(t.static for t in tools),
        serial_p2g=sim.p2g == "serial" or (sim.p2g == "auto" and arch == "cpu"),
        svd=sim.svd,
    )
    key = (layout, sim.particle_lower_bound_cells, sim.boundary_cells)
    if key not in _SIMULATORS:
        _SIMULATORS[key] = MPMSimulator(layout, sim.particle_lower_bound_cells, sim.boundary_cells, arch)
    simulator = _SIMULATORS[key]
    simulator.adjoint_memory_bytes = int(sim.adjoint_memory_mb * 2**20)
    simulator.set_gravity(sim.gravity_m_s2)
    simulator.set_softness(sim.contact_softness)
    simulator.set_expel_rates(expel_rates(sim, tools))
    simulator.set_tools(tuple(stopped_knife(sim, t) for t in tools))
    return simulator


def stopped_knife(sim: SimConfig, tool: ToolConfig) -> ToolConfig:
    """``tool`` with a knife's y lower bound raised so that its V edge stops ``sim.knife_floor_depth`` below
    the floor; any other tool, or no ``knife_floor_depth``, unchanged."""
    if tool.kind != "knife" or sim.knife_floor_depth is None:
        return tool
    lowest = floor_height(sim) + tool.blade_depth - sim.knife_floor_depth
    lower = (tool.lower_bound[0], max(tool.lower_bound[1], lowest), tool.lower_bound[2])
    upper = (tool.upper_bound[0], max(tool.upper_bound[1], lower[1]), tool.upper_bound[2])
    return tool.model_copy(update={"lower_bound": lower, "upper_bound": upper})
