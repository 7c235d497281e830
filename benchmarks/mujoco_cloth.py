"""MuJoCo flex-cloth peer benchmark: the MuJoCo side of the cloth speed comparison.

Builds the reference scene (a 0.5 m x 0.5 m cloth of 32 x 32 vertices hanging in the x-z plane from
its two top corners, under gravity and a constant +y wind) as an MJCF string with a 2D
``<flexcomp>``, steps it with MuJoCo and reports wall-clock throughput plus a few physical sanity
figures. Mapping onto MuJoCo (checked against MuJoCo 4.0.0): the membrane is the flex's
Saint Venant-Kirchhoff shell (``<elasticity elastic2d="both">``) whose stretching energy per unit
area is ``t`` times the plane-stress density, so Young's modulus ``E`` and thickness ``t`` are
chosen with ``E * t = stretch_stiffness_n_per_m``; its hinge bending rigidity is
``D = E t^3 / (12 (1 - nu^2))``, so ``t = sqrt(12 (1 - nu^2) D / (E t))`` reproduces
``bend_stiffness_nm`` exactly (``elastic2d="stretch"`` with t = 1 mm when the bending stiffness is
zero). Mass is spread uniformly over the vertices (flexcomp gives every point ``mass / npoint``,
i.e. no area lumping, so edge and corner vertices are slightly heavier than with a lumped-area
mass). MuJoCo has no aerodynamic model for flex triangles; wind acts through the global fluid
model (``<option wind density viscosity>``) on the vertex *bodies* using the inertia-based model:
each vertex body's equivalent inertia box is a cube (flexcomp ``inertiabox``, which MuJoCo uses as
the box half-size) sized so that one face has the vertex's share of the cloth area
``size^2 / n_vert``, giving per vertex ``f_i = -1/2 rho A |u_i| u_i`` per world axis with
``u = v - wind`` (drag coefficient 1, plus negligible Stokes drag from the air viscosity). Unlike a
per-triangle model, this drag is isotropic: it ignores the cloth normal, so flow parallel to the
sheet is resisted as strongly as flow through it and a cloth tilted by the wind keeps catching the
full wind instead of presenting a smaller projected area (the cloth is therefore blown further
than a normal-projected triangle model would predict). Flex contacts and self-collision are
disabled (no colliders in the scene), Rayleigh damping is zero, and only ``mj_step`` is timed.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from typing import Any

from sim2real.study.mujoco_flex import AIR_DENSITY_KG_M3, AIR_VISCOSITY_PA_S, elastic_params

_DEFAULT_INTEGRATOR = "discrete"
# Tried in order if the installed MuJoCo rejects the preferred integrator for 2D flex elasticity.
_INTEGRATOR_FALLBACKS = ("discrete", "implicitfast", "implicit")


def build_mujoco_cloth_xml(
    *,
    vert_per_side: int = 32,
    size_m: float = 0.5,
    density_kg_m2: float = 0.284,
    stretch_stiffness_n_per_m: float = 100.0,
    poisson: float = 0.3,
    bend_stiffness_nm: float = 1e-5,
    wind_speed_m_s: float = 3.0,
    dt_s: float = 0.005,
    integrator: str = _DEFAULT_INTEGRATOR,
) -> str:
    """Build the MJCF string of the hanging, wind-blown cloth scene.

    The cloth is a ``vert_per_side`` x ``vert_per_side`` grid flexcomp in the x-z plane, centred on
    x = 0, with its top edge at z = 1 m and its two top corner vertices pinned to the world.

    Args:
        vert_per_side: Number of vertices along each side of the square cloth.
        size_m: Side length of the cloth in metres.
        density_kg_m2: Areal density; the total mass ``density * size^2`` is split evenly over the
            vertices.
        stretch_stiffness_n_per_m: Membrane stiffness ``E * t`` in N/m.
        poisson: Poisson's ratio of the membrane, in ``[0, 0.5)``.
        bend_stiffness_nm: Plate bending rigidity ``D`` in N*m; 0 disables bending.
        wind_speed_m_s: Wind velocity along +y in m/s (perpendicular to the cloth plane).
        dt_s: Time step in seconds.
        integrator: MuJoCo integrator name; ``"discrete"`` is what MuJoCo 4.0 needs for implicit
            2D flex elasticity.

    Returns:
        The MJCF model as a string, ready for ``mujoco.MjModel.from_xml_string``.

    Raises:
        ValueError: If a parameter is out of range.
    """
    if vert_per_side < 2:
        raise ValueError("vert_per_side must be at least 2")
    if size_m <= 0.0 or density_kg_m2 <= 0.0 or dt_s <= 0.0:
        raise ValueError("size_m, density_kg_m2 and dt_s must be positive")
    young, thickness, elastic2d = elastic_params(
        stretch_stiffness_n_per_m, poisson, bend_stiffness_nm
    )
    n = vert_per_side
    spacing = size_m / (n - 1)
    total_mass = density_kg_m2 * size_m * size_m
    # Fluid drag face area per vertex body = (2 * inertiabox)^2 = size^2 / n^2 (cloth area share).
    inertiabox = size_m / (2.0 * n)
    # Grid is generated in the flexcomp's local x-y plane, centred on its origin; rotating by +90
    # degrees about x maps local y onto world z, so grid row y = n-1 is the top edge.
    centre_z = 1.0 - 0.5 * size_m
    radius = min(1e-3, 0.1 * spacing)
    return f"""<mujoco model="mujoco_cloth_benchmark">
  <option timestep="{dt_s!r}" integrator="{integrator}" solver="Newton" gravity="0 0 -9.81"
          wind="0 {wind_speed_m_s!r} 0" density="{AIR_DENSITY_KG_M3!r}"
          viscosity="{AIR_VISCOSITY_PA_S!r}"/>
  <worldbody>
    <flexcomp name="cloth" type="grid" dim="2" count="{n} {n} 1"
              spacing="{spacing!r} {spacing!r} {spacing!r}" pos="0 0 {centre_z!r}" euler="90 0 0"
              mass="{total_mass!r}" inertiabox="{inertiabox!r}" radius="{radius!r}">
      <contact contype="0" conaffinity="0" selfcollide="none"/>
      <elasticity young="{young!r}" poisson="{poisson!r}" thickness="{thickness!r}"
                  elastic2d="{elastic2d}"/>
      <pin grid="0 {n - 1} {n - 1} {n - 1}"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""


def _compile(mujoco: Any, scene_kwargs: dict[str, Any]) -> tuple[Any, str, list[str]]:
    """Compile the scene, trying the preferred integrator first; return model, name, errors."""
    errors: list[str] = []
    requested = scene_kwargs.pop("integrator", None)
    candidates = (requested,) if requested else _INTEGRATOR_FALLBACKS
    for name in candidates:
        xml = build_mujoco_cloth_xml(integrator=name, **scene_kwargs)
        try:
            return mujoco.MjModel.from_xml_string(xml), name, errors
        except ValueError as exc:  # MuJoCo reports XML/compile errors as ValueError.
            errors.append(f"{name}: {exc}")
    raise ValueError("; ".join(errors))


def run_mujoco_cloth(*, duration_s: float = 2.0, repeats: int = 3, **scene_kwargs: Any) -> dict:
    """Simulate the MuJoCo cloth scene ``repeats`` times and report speed and sanity figures.

    The model is compiled once; each repeat resets the data, runs ``mj_forward`` and then times
    only the ``mj_step`` loop with ``time.perf_counter``.

    Args:
        duration_s: Simulated time per repeat in seconds.
        repeats: Number of timed repeats (at least 1).
        **scene_kwargs: Keyword arguments forwarded to :func:`build_mujoco_cloth_xml`.

    Returns:
        A dict with ``available`` (False plus ``reason`` when mujoco cannot be imported or the
        scene does not compile), ``mujoco_version``, ``integrator``, ``solver``, ``vert_count``,
        ``dt_s``, ``steps``, ``sim_seconds``, ``wall_s_median``, ``wall_s_all``,
        ``sim_vertex_seconds_per_wall_s``, ``vertex_steps_per_wall_s``, ``wall_s_per_sim_s``,
        ``final_max_speed_m_s``, ``final_finite``, ``final_min_z`` and
        ``final_mean_y_displacement_m``, plus descriptive extras (material mapping, aerodynamic
        model, compile time).
    """
    try:
        import mujoco
        import numpy as np
    except (ImportError, OSError) as exc:
        return {"available": False, "reason": f"cannot import mujoco: {exc!r}"}

    if repeats < 1:
        raise ValueError("repeats must be at least 1")
    kwargs = dict(scene_kwargs)
    n = int(kwargs.get("vert_per_side", 32))
    size_m = float(kwargs.get("size_m", 0.5))
    dt_s = float(kwargs.get("dt_s", 0.005))
    young, thickness, elastic2d = elastic_params(
        float(kwargs.get("stretch_stiffness_n_per_m", 100.0)),
        float(kwargs.get("poisson", 0.3)),
        float(kwargs.get("bend_stiffness_nm", 1e-5)),
    )

    t0 = time.perf_counter()
    try:
        model, integrator, integrator_errors = _compile(mujoco, kwargs)
    except ValueError as exc:
        return {
            "available": False,
            "reason": f"scene does not compile: {exc}",
            "mujoco_version": mujoco.__version__,
        }
    compile_s = time.perf_counter() - t0
    data = mujoco.MjData(model)

    steps = max(1, round(duration_s / dt_s))
    sim_seconds = steps * model.opt.timestep
    vert_count = int(model.flex_vertnum[0])
    step = mujoco.mj_step
    wall_all: list[float] = []
    y0 = None
    for _ in range(repeats):
        mujoco.mj_resetData(model, data)
        mujoco.mj_forward(model, data)
        if y0 is None:
            y0 = data.flexvert_xpos[:, 1].copy()
        start = time.perf_counter()
        for _ in range(steps):
            step(model, data)
        wall_all.append(time.perf_counter() - start)

    wall_med = statistics.median(wall_all)
    pos = np.asarray(data.flexvert_xpos)
    # Every free vertex owns three orthonormal slide dofs (rotation-invariant norm); pinned: none.
    speeds = np.linalg.norm(np.asarray(data.qvel).reshape(-1, 3), axis=1)
    finite = bool(np.isfinite(pos).all() and np.isfinite(data.qvel).all())
    # Equivalent inertia box of a free vertex body: its face area is the drag area per vertex.
    free_body = int(model.flex_vertbodyid[np.flatnonzero(model.flex_vertbodyid > 0)[0]])
    inertia = model.body_inertia[free_body]
    mass = float(model.body_mass[free_body])
    half = np.sqrt(1.5 / mass * (inertia.sum() - 2.0 * inertia))
    return {
        "available": True,
        "mujoco_version": mujoco.__version__,
        "integrator": integrator,
        "integrator_errors": integrator_errors,
        "solver": "Newton",
        "vert_count": vert_count,
        "dof_count": int(model.nv),
        "dt_s": float(model.opt.timestep),
        "steps": steps,
        "sim_seconds": sim_seconds,
        "repeats": repeats,
        "compile_s": compile_s,
        "wall_s_median": wall_med,
        "wall_s_all": wall_all,
        "sim_vertex_seconds_per_wall_s": vert_count * sim_seconds / wall_med,
        "vertex_steps_per_wall_s": vert_count * steps / wall_med,
        "wall_s_per_sim_s": wall_med / sim_seconds,
        "final_max_speed_m_s": float(speeds.max()) if speeds.size else 0.0,
        "final_finite": finite,
        "final_min_z": float(pos[:, 2].min()),
        "final_mean_y_displacement_m": float((pos[:, 1] - y0).mean()),
        "elastic2d": elastic2d,
        "young_pa": young,
        "thickness_m": thickness,
        "total_mass_kg": float(model.body_mass.sum()),
        "mass_model": "uniform per vertex (flexcomp mass / npoint); pinned vertices carry none",
        "drag_area_per_vertex_m2": float(4.0 * half[1] * half[2]),
        "aero_model": (
            "MuJoCo inertia-box fluid model on vertex bodies: f = -0.5 rho A |u_i| u_i per axis, "
            "u = v - wind, A = size^2/n_vert, rho = 1.2; isotropic, no triangle-normal projection"
        ),
        "size_m": size_m,
        "vert_per_side": n,
    }


def main(argv: list[str] | None = None) -> dict:
    """``python -m benchmarks.mujoco_cloth``: run the scene and print the result as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=2.0, help="simulated seconds per repeat")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats")
    args = parser.parse_args(argv)
    if not args.duration > 0 or args.repeats < 1:
        parser.error("--duration must be > 0 and --repeats >= 1")
    result = run_mujoco_cloth(duration_s=args.duration, repeats=args.repeats)
    print(json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    main()
