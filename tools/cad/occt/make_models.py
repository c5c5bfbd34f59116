"""Writes STEP models with OpenCascade, a CAD kernel strand does not use, so strand-cad is tested on files
another writer made: `python3 make_models.py OUT_DIR` (needs `pip install cadquery-ocp-novtk`).

Beside each model it writes `<name>.faces.json`: OpenCascade's own reading of the file it wrote, one
object per face in the file's order (surface type, area in m², bounding box in m), which the Rust test
compares strand-cad's `--list-faces` figures with.
"""
import json
import sys
from pathlib import Path

from OCP.BRepAdaptor import BRepAdaptor_Surface
from OCP.BRepBndLib import BRepBndLib
from OCP.BRepFilletAPI import BRepFilletAPI_MakeFillet
from OCP.BRepGProp import BRepGProp
from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox, BRepPrimAPI_MakeCone, BRepPrimAPI_MakeCylinder
from OCP.Bnd import Bnd_Box
from OCP.GProp import GProp_GProps
from OCP.GeomAbs import (GeomAbs_BSplineSurface, GeomAbs_Cone, GeomAbs_Cylinder, GeomAbs_Plane,
                         GeomAbs_Sphere, GeomAbs_Torus)
from OCP.IFSelect import IFSelect_RetDone
from OCP.Interface import Interface_Static
from OCP.STEPControl import STEPControl_AsIs, STEPControl_Reader, STEPControl_Writer
from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE
from OCP.TopExp import TopExp_Explorer
from OCP.TopoDS import TopoDS

TYPES = {GeomAbs_Plane: "plane", GeomAbs_Cylinder: "cylinder", GeomAbs_Cone: "cone", GeomAbs_Sphere: "sphere",
         GeomAbs_Torus: "torus", GeomAbs_BSplineSurface: "b-spline"}


def write(shape, path, unit="MM"):
    Interface_Static.SetCVal_s("write.step.unit", unit)
    w = STEPControl_Writer()
    w.Transfer(shape, STEPControl_AsIs)
    assert w.Write(str(path)) == IFSelect_RetDone, path


def faces_of(path):
    """OpenCascade's reading of a STEP file, in metres (it converts the file's unit to mm)."""
    r = STEPControl_Reader()
    assert r.ReadFile(str(path)) == IFSelect_RetDone, path
    r.TransferRoots()
    shape = r.OneShape()
    out = []
    e = TopExp_Explorer(shape, TopAbs_FACE)
    while e.More():
        face = TopoDS.Face(e.Current())
        props = GProp_GProps()
        BRepGProp.SurfaceProperties_s(face, props)
        box = Bnd_Box()
        BRepBndLib.AddOptimal_s(face, box, False, False)
        lo, hi = box.CornerMin(), box.CornerMax()
        x0, y0, z0, x1, y1, z1 = lo.X(), lo.Y(), lo.Z(), hi.X(), hi.Y(), hi.Z()
        out.append({"type": TYPES.get(BRepAdaptor_Surface(face).GetType(), "other"),
                    "area_m2": props.Mass() * 1e-6,
                    "bbox_min": [x0 * 1e-3, y0 * 1e-3, z0 * 1e-3], "bbox_max": [x1 * 1e-3, y1 * 1e-3, z1 * 1e-3]})
        e.Next()
    return out


def main():
    out = Path(sys.argv[1] if len(sys.argv) > 1 else ".")
    out.mkdir(parents=True, exist_ok=True)
    # A cylinder, r 20 mm, 40 mm high: a periodic face with a seam edge, two discs bounded by circles.
    cylinder = BRepPrimAPI_MakeCylinder(20.0, 40.0).Shape()
    # A box 60 x 40 x 20 mm with its four top edges rounded (r 5 mm): planes trimmed by the rounds,
    # cylinders, and the rounds' corner blends.
    box = BRepPrimAPI_MakeBox(60.0, 40.0, 20.0).Shape()
    fillet = BRepFilletAPI_MakeFillet(box)
    e = TopExp_Explorer(box, TopAbs_EDGE)
    while e.More():
        edge = TopoDS.Edge(e.Current())
        b = Bnd_Box()
        BRepBndLib.Add_s(edge, b)
        if b.CornerMin().Z() > 19.9:  # the top edges: both ends at z = 20
            fillet.Add(5.0, edge)
        e.Next()
    rounded = fillet.Shape()
    # A cone frustum written in inches (r 1 in → 0.5 in, 2 in high): the unit conversion.
    cone = BRepPrimAPI_MakeCone(25.4, 12.7, 50.8).Shape()
    for name, shape, unit in [("occt_cylinder", cylinder, "MM"), ("occt_rounded_box", rounded, "MM"), ("occt_cone_inch", cone, "INCH")]:
        path = out / f"{name}.step"
        write(shape, path, unit)
        (out / f"{name}.faces.json").write_text(json.dumps(faces_of(path), indent=1) + "\n")
        print("wrote", path)


if __name__ == "__main__":
    main()
