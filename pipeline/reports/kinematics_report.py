"""The kinematics report: per machine its errors and plays, seed 003's Tables 4-5 (smallest
and largest comprehensive error per tilt angle at C = 0 and per C at tilt 0) and the field
drawn as its Figures 11-12: the comprehensive error over the workpiece's mid-height plane at
tilt 0, 30, 45, 60, 90 deg (C = 0) and at C 0, 30, 60, 90 deg (tilt 0)."""

from __future__ import annotations

import html
import re
from pathlib import Path

import numpy as np

from pipeline.reports.report_page import new_figure, save_figure, write_page

FIELD_TILTS = (0.0, 30.0, 45.0, 60.0, 90.0)
FIELD_C = (0.0, 30.0, 60.0, 90.0)


def plot_field(machine, workspace_mm: float, path) -> Path:
    """One PNG: the comprehensive error |dp| [um] on the plane z = W / 2 of the workpiece
    cube, top row per tilt angle (C = 0), bottom row per C (tilt 0)."""
    from features.probing import axes_of
    from models.machine.kinematics import field_um

    tilt, _ = axes_of(machine.kinematics)
    n = 41
    xy = np.linspace(-workspace_mm, workspace_mm, n)
    gx, gy = np.meshgrid(xy, xy, indexing="xy")
    pts = np.c_[gx.ravel(), gy.ravel(), np.full(gx.size, workspace_mm / 2)]
    panels = [(f"{tilt} = {a:g}°, C = 0°", a, 0.0) for a in FIELD_TILTS] + [
        (f"{tilt} = 0°, C = {c:g}°", 0.0, c) for c in FIELD_C]
    maps = [field_um(machine.ident, pts, np.full(len(pts), a), np.full(len(pts), c))[2]
            .reshape(n, n) for _, a, c in panels]
    top = max(float(np.nanmax(m)) if np.isfinite(m).any() else 0.0 for m in maps) or 1.0
    fig, axes = new_figure(15, 6.4, nrows=2, ncols=5)
    image = None
    for ax, (title, _, _), values in zip(axes.ravel(), panels, maps):
        image = ax.pcolormesh(xy, xy, values, vmin=0, vmax=top, cmap="viridis",
                              shading="auto")
        ax.set_title(title, fontsize=9)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    axes[1, 4].axis("off")
    fig.colorbar(image, ax=axes.ravel().tolist(), label="comprehensive error ΔE [um]")
    fig.suptitle(f"{machine.machine_id} visit {machine.visit}: error field at z = "
                 f"{workspace_mm / 2:g} mm (x, y [mm], table frame)")
    return save_figure(fig, path)


def _cell(value) -> str:
    return "-" if value is None else f"{value:.4g}"


def _tables_html(machine) -> str:
    from features.probing import axes_of

    tilt, _ = axes_of(machine.kinematics)
    parts = []
    for key, fixed, axis in (("tilt", "C = 0°", tilt), ("c", f"{tilt} = 0°", "C")):
        rows = machine.tables[key]
        head = "".join(f"<th>{a:g}°</th>" for a in rows)
        lo = "".join(f"<td>{_cell(None if c['min_um'] is None else c['min_um'] / 1000)}</td>"
                     for c in rows.values())
        hi = "".join(f"<td>{_cell(None if c['max_um'] is None else c['max_um'] / 1000)}</td>"
                     for c in rows.values())
        parts.append(f"<p>Comprehensive error per {axis} angle at {fixed} [mm] (seed 003 "
                     f"Table {4 if key == 'tilt' else 5})</p><table><tr><th></th>{head}</tr>"
                     f"<tr><td>ΔE min</td>{lo}</tr><tr><td>ΔE max</td>{hi}</tr></table>")
    return "".join(parts)


def _errors_html(machine) -> str:
    j = machine.to_dict()
    rows = "".join(
        f"<tr><td>{html.escape(n)}</td><td>{_cell(v)}</td><td>{_cell(j['errors_u'][n])}</td>"
        f"<td>{'' if v is not None else 'not identifiable'}</td></tr>"
        for n, v in j["errors"].items())
    rows += "".join(f"<tr><td>{html.escape(c['label'])}</td><td>{_cell(c['value'])}</td>"
                    f"<td>{_cell(c['u'])}</td><td>identifiable combination</td></tr>"
                    for c in j["identifiable_combinations"])
    rows += "".join(f"<tr><td>play {a} [arcsec]</td><td>{_cell(v)}</td>"
                    f"<td>{_cell(j['play_u_arcsec'][a])}</td><td></td></tr>"
                    for a, v in j["play_arcsec"].items())
    return ("<table><tr><th>error [um, urad]</th><th>value</th><th>u (k = 1)</th><th></th></tr>"
            f"{rows}</table>")


def write_report(result, out) -> dict[str, Path]:
    """``kinematics.html`` and one field plot per machine and visit under ``out``."""
    out = Path(out)
    files, body = {}, []
    for m in result.machines:
        stem = re.sub(r"[^\w.-]", "_", f"field_{m.machine_id}_{m.visit}", flags=re.ASCII)
        png = plot_field(m, result.workspace_mm, out / f"{stem}.png")
        files[f"plot {png.name}"] = png
        body.append(f"<h2>{html.escape(m.machine_id)} visit {html.escape(m.visit)} "
                    f"({html.escape(m.kinematics)})</h2><p class=\"summary\">residual "
                    f"{m.ident.residual_rms_um:.3g} um rms over {m.ident.points} centres; "
                    f"workpiece cube x, y ±{result.workspace_mm:g} mm, z 0 to "
                    f"{result.workspace_mm:g} mm</p>{_errors_html(m)}{_tables_html(m)}"
                    f'<p><img src="{html.escape(png.name)}" alt="{html.escape(png.stem)}"></p>')
    notes = "".join(f'<p class="alert">{html.escape(n)}</p>' for n in result.notes)
    files["html"] = write_page(out / "kinematics.html", "Rotary axes: kinematic errors "
                               "from probing", f"<p>{html.escape(result.source)}</p>{notes}"
                               + "".join(body))
    return files
