"""Prints the markdown table of the material presets (configs/materials/) that docs/materials.md shows.

    python tools/presets_table.py

One row per brittle preset: the real material's E, density, tensile strength, fracture energy and
Weibull modulus, the softening k, the simulated E and strength, the wave speeds, Hillerborg's
length, the impact stress over the strength at the documented speed (real and simulated) and the
energy a crack spends per unit area over G_f on a grid of 1/64 m cells (above 1: the band snaps); then
the elastic presets, then the NACC presets (the paper's Table 1 rows) with their keys.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fracture_gs.materials import BrittleMaterial  # noqa: E402
from fracture_gs.materials.presets import (available, characteristic_length, impact_ratio,  # noqa: E402
                                           load_preset, p_wave_speed)

CELL = 1.0 / 64.0   # the cell size of the crack-energy column (a 1 m domain on a 64³ grid)


def brittle_rows(names: list[str]) -> list[str]:
    lines = ["| preset | E real → sim (Pa) | ρ (kg/m³) | σ_F real → sim (Pa) | G_f (J/m²) | Weibull m | k "
             "| c_p real → sim (m/s) | l_ch (mm) | ρ c v / σ_F at v real / sim | crack energy / G_f at dx = 1/64 m |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in names:
        preset = load_preset(name)
        real, sim = preset.real, preset.keys
        c_real = p_wave_speed(real["E"], real["nu"], real["density"])
        c_sim = p_wave_speed(sim["E"], sim["nu"], sim["density"])
        lines.append(
            f"| `{name}` | {real['E']:.3g} → {sim['E']:.4g} | {sim['density']:g} | {real['strength']:.3g} → "
            f"{sim['strength']:.4g} | {sim['fracture_energy']:g} | {sim.get('weibull_m', 0):g} | {preset.softening:g} "
            f"| {c_real:.0f} → {c_sim:.0f} | {1e3 * characteristic_length(sim):.2g} "
            f"| {impact_ratio(real, preset.speed):.3f} / {impact_ratio(sim, preset.speed):.3f} at {preset.speed:g} m/s "
            f"| {BrittleMaterial(**sim).band_energy_ratio(CELL):.1f} |")
    return lines


def elastic_rows(names: list[str]) -> list[str]:
    lines = ["| preset | E real → sim (Pa) | ν | ρ (kg/m³) | k | c_p real → sim (m/s) |", "|---|---|---|---|---|---|"]
    for name in names:
        preset = load_preset(name)
        real, sim = preset.real, preset.keys
        lines.append(f"| `{name}` | {real['E']:.3g} → {sim['E']:.4g} | {sim['nu']:g} | {sim['density']:g} "
                     f"| {preset.softening:g} | {p_wave_speed(real['E'], real['nu'], real['density']):.0f} → "
                     f"{p_wave_speed(sim['E'], sim['nu'], sim['density']):.0f} |")
    return lines


def nacc_rows(names: list[str]) -> list[str]:
    lines = ["| preset | E | ν | density | Jp0 | β | ξ | M |", "|---|---|---|---|---|---|---|---|"]
    for name in names:
        keys = load_preset(name).keys
        lines.append(f"| `{name}` | {keys['E']:g} | {keys['nu']:g} | {keys['density']:g} | {keys['Jp0']:g} "
                     f"| {keys['beta']:g} | {keys['xi']:g} | {keys['M']:g} |")
    return lines


def main() -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    names = available()
    brittle = [name for name in names if load_preset(name).model == "brittle"]
    elastic = [name for name in names if load_preset(name).model == "elastic"]
    nacc = [name for name in names if load_preset(name).model == "nacc"]
    print("\n".join(brittle_rows(brittle)))
    print()
    print("\n".join(elastic_rows(elastic)))
    print()
    print("\n".join(nacc_rows(nacc)))


if __name__ == "__main__":
    main()
