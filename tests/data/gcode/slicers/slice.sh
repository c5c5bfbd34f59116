#!/bin/sh
# Regenerates the slicer corpus: tests/data/gcode/{cura,prusaslicer25,slic3r13}/*.gcode from the
# parts make_parts.py writes (tests/data/gcode/slicers/parts/*.stl). Each slicer runs with its own
# defaults and its own default start and end G-code; the only settings given are listed below.
#
# Tested on Debian 12 (bookworm), amd64, with:
#   cura-engine   1:4.13.0-1+b1    CuraEngine 4.13.0 ("Cura_SteamEngine 4.13.0")
#   cura          4.13.0-1         only its resources: machine definitions, quality and nozzle profiles
#   fdm-materials 4.13.0-1         only generic_pla_175.xml.fdm_material (the Ender-3's default material)
#   prusa-slicer  2.5.0+dfsg-4     PrusaSlicer 2.5.0, and its bundled vendor profiles
#   slic3r        1.3.0+dfsg1-5+b2 Slic3r 1.3.0
#   python3       (3.11) for the helpers; no Python packages
#
#   apt-get install -y cura-engine prusa-slicer slic3r
#   tests/data/gcode/slicers/slice.sh            # from the repository root
#
# The cura package (the Qt application) is not installed: its .deb and fdm-materials' are fetched
# with `apt-get download` and unpacked into a temporary folder for their resources; set
# CURA_RESOURCES to use an installed /usr/share/cura/resources instead.
#
# What each slicer gets:
#   cura/ender3_*.gcode         CuraEngine 4.13, machine creality_ender3 (235 x 235 bed), with the
#                               settings the Cura 4.13 front end would send for a new Ender-3:
#                               "Standard Quality" (0.2 mm), generic PLA 1.75 mm, 0.4 mm nozzle,
#                               every `value` formula evaluated (cura_slice.py). Start code: the
#                               Ender-3's ("Ender 3 Custom Start G-code"); end code: creality_base's
#                               (ends with `M84 X Y E`), {machine_depth} replaced by 235 as Cura does.
#                               The evaluated settings that differ from the definitions'
#                               default_value: slicers/cura_ender3_settings.txt.
#                               Override: none (the STL is centred on x = y = 0 and CuraEngine adds
#                               half the bed, machine_center_is_zero = false).
#   prusaslicer25/default_*.gcode  prusa-slicer 2.5.0 with no config at all: its built-in defaults
#                               (0.3 mm layers, 200 x 200 bed, start `G28` / `G1 Z5 F5000`, end
#                               `M104 S0` / `G28 X0` / `M84`), the part centred on the bed.
#   prusaslicer25/mk3s_*.gcode  prusa-slicer 2.5.0 --load mk3s.ini: the bundled PrusaResearch.ini
#                               preset "Original Prusa i3 MK3S & MK3S+" with its default print and
#                               filament presets ("0.15mm QUALITY @MK3", "Prusament PLA"), flattened by
#                               prusa_preset.py (each file ends with the full configuration).
#   slic3r13/default_*.gcode    slic3r 1.3.0 --no-gui with no config: its built-in defaults (0.3 mm
#                               layers, start `G28` / `G1 Z5 F5000`, end `M104 S0` / `G28 X0` / `M84`).
#
# Reruns give the same CuraEngine files; PrusaSlicer's and Slic3r's carry the time of slicing, and
# PrusaSlicer's seam points can move by a few hundredths of a millimetre from run to run.
set -eu

here=$(cd "$(dirname "$0")" && pwd)
data=$(cd "$here/.." && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

python3 "$here/make_parts.py" "$here/parts"
parts="box20 cyl20 wedge45 tower_hole"

# CuraEngine
if [ -z "${CURA_RESOURCES:-}" ]; then
    (cd "$tmp" && apt-get download cura fdm-materials >/dev/null 2>&1)
    for deb in "$tmp"/*.deb; do dpkg-deb -x "$deb" "$tmp/root"; done
    CURA_RESOURCES="$tmp/root/usr/share/cura/resources"
fi
mkdir -p "$data/cura"
for p in $parts; do
    python3 "$here/cura_slice.py" "$CURA_RESOURCES" creality_ender3 "$here/parts/$p.stl" "$data/cura/ender3_$p.gcode" \
        --settings-out "$here/cura_ender3_settings.txt"
done

# PrusaSlicer 2.5
mkdir -p "$data/prusaslicer25"
python3 "$here/prusa_preset.py" /usr/share/PrusaSlicer/profiles/PrusaResearch.ini "Original Prusa i3 MK3S & MK3S+" \
    > "$tmp/mk3s.ini"
for p in $parts; do
    prusa-slicer --loglevel 1 --export-gcode "$here/parts/$p.stl" -o "$data/prusaslicer25/default_$p.gcode" >/dev/null
    prusa-slicer --loglevel 1 --load "$tmp/mk3s.ini" --export-gcode "$here/parts/$p.stl" \
        -o "$data/prusaslicer25/mk3s_$p.gcode" >/dev/null
done

# Slic3r 1.3
mkdir -p "$data/slic3r13"
for p in $parts; do
    slic3r --no-gui "$here/parts/$p.stl" -o "$data/slic3r13/default_$p.gcode" >/dev/null
done

ls -l "$data/cura" "$data/prusaslicer25" "$data/slic3r13"
