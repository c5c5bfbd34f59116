#!/usr/bin/env python3
"""Writes helix_cylinder.gcode: a 600 mm cylinder printed as one helix (spiral vase) on the
rotary table of cells/kr6-turntable, the table turning under a nearly still arm. Its far side is
1.0 m from the arm's base, beyond the KR 6 R900's reach: only a turning table can print it.

The points are on the part as it stands with the table at 0 (bed coordinates, mm; the table's axis
at bed (125, 125)). Each point p(phi) of the helix is paired with the table angle C = -(phi - phi0)
degrees, which turns it to the same place beside the table (phi0 = 180 deg: the side facing the
robot), so the nozzle stays there and only climbs. The feed is the nozzle's speed over the part.

    python3 make_helix.py > helix_cylinder.gcode
"""
import math

RADIUS = 300.0         # mm
CENTRE = (125.0, 125.0)
LAYER = 0.3            # mm per turn
TURNS = 4
STEP_DEG = 1.0         # one line per degree of turn (5.2 mm chords, 0.011 mm sag)
WIDTH = 0.5            # mm bead width
FILAMENT = 1.75        # mm
FEED = 40.0            # mm/s over the part
PHI0 = 180.0           # deg: where the nozzle stays (the side facing the robot, 0.4 m from its base)

e_per_mm = WIDTH * LAYER / (math.pi * (FILAMENT / 2) ** 2)


def point(phi_deg, z):
    a = math.radians(phi_deg)
    return CENTRE[0] + RADIUS * math.cos(a), CENTRE[1] + RADIUS * math.sin(a), z


print("; helix_cylinder.gcode: a 600 mm cylinder as one helix on a rotary table (tests/data/gcode/turntable/make_helix.py)")
print(f"; radius {RADIUS} mm, {TURNS} turns of {LAYER} mm, {FEED} mm/s over the part; C turns the table (degrees)")
print("G21 ; mm")
print("G90 ; absolute XYZ and C")
print("M83 ; relative E")
x, y, z = point(PHI0, LAYER)
print(f"G0 X{x:.4f} Y{y:.4f} Z{LAYER + 5:.4f} C0 F3000 ; above the start")
print(f"G0 X{x:.4f} Y{y:.4f} Z{LAYER:.4f} C0 F600")
print(";TYPE:External perimeter")
print(f"G1 F{FEED * 60:.0f}")
steps = int(round(TURNS * 360 / STEP_DEG))
prev = (x, y, LAYER)
for k in range(1, steps + 1):
    turned = k * STEP_DEG
    z = LAYER + LAYER * turned / 360.0
    x, y, z = point(PHI0 + turned, z)
    length = math.dist(prev, (x, y, z))
    print(f"G1 X{x:.4f} Y{y:.4f} Z{z:.4f} C{-turned:.3f} E{length * e_per_mm:.5f}")
    prev = (x, y, z)
print(f"G1 Z{prev[2] + 5:.4f} F600 ; up and off")
print("; end")
