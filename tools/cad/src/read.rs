//! Reading a STEP file into faces, one at a time so that one bad face is named, not lost. truck-stepio
//! converts a whole shell at once and, where it cannot convert an entity, prints to stderr and drops
//! it (a dropped edge even shifts the indices of the later ones); bad knot vectors panic. So each face
//! is converted as a shell of its own, under `catch_unwind`, and checked: it came through, its loops
//! are closed, its geometry is finite. What fails becomes a [`CadError::Entity`] with the face's or
//! its surface's `#id`.

use std::collections::HashMap;
use std::panic::{AssertUnwindSafe, catch_unwind};

use ruststep::ast::{EntityInstance, Name, Parameter, Record};
use ruststep::tables::{IntoOwned, PlaceHolder};
use truck_stepio::r#in::{FaceAnyHolder, FaceSurfaceHolder, ShellHolder, Table};

use crate::CadError;
use crate::face::{ReadShell, StepFace};

/// A STEP model's faces.
#[derive(Debug)]
pub struct Model {
    /// The file, as given.
    pub file: String,
    /// The file's length unit (m per unit): 0.001 for millimetres.
    pub metres_per_unit: f64,
    /// False when the file names no length unit and millimetres were assumed.
    pub unit_named: bool,
    /// Every face of every shell, in the file's order (shells by instance number); a face shared by
    /// two shells once.
    pub faces: Vec<StepFace>,
}

impl Model {
    /// Face `index` (as `--list-faces` numbers them), or an error listing how many there are.
    pub fn face(&self, index: usize) -> Result<&StepFace, CadError> {
        self.faces.get(index).ok_or_else(|| CadError::Model {
            file: self.file.clone(),
            reason: format!(
                "no face {index}: the model has {} faces, numbered 0 to {}",
                self.faces.len(),
                self.faces.len().saturating_sub(1)
            ),
        })
    }

    /// The face named `name` (the STEP face's label), or an error listing the names there are.
    pub fn face_named(&self, name: &str) -> Result<&StepFace, CadError> {
        let mut matching = self.faces.iter().filter(|f| f.name == name);
        match (matching.next(), matching.next()) {
            (Some(f), None) => Ok(f),
            (Some(_), Some(_)) => Err(CadError::Model {
                file: self.file.clone(),
                reason: format!("more than one face is named {name:?}: choose one by its index (--list-faces)"),
            }),
            (None, _) => {
                let names: Vec<&str> = self.faces.iter().map(|f| f.name.as_str()).filter(|n| !n.is_empty()).collect();
                Err(CadError::Model {
                    file: self.file.clone(),
                    reason: if names.is_empty() {
                        format!("no face is named {name:?}: the model's faces have no names; choose one by its index (--list-faces)")
                    } else {
                        format!("no face is named {name:?}; the names are: {}", names.join(", "))
                    },
                })
            }
        }
    }
}

/// Parses STEP text (`file` names it in errors).
pub fn parse_step(text: &str, file: &str) -> Result<Model, CadError> {
    let parse = |reason: String| CadError::Parse { file: file.to_string(), reason };
    let exchange = catch_unwind(|| ruststep::parser::parse(text))
        .map_err(|p| parse(format!("the parser failed: {}", panic_message(&*p))))?
        .map_err(|e| parse(e.to_string().lines().next().unwrap_or("syntax error").to_string()))?;
    let data = exchange.data.first().ok_or_else(|| parse("no DATA section".to_string()))?;
    let entities = EntityNames::of(&data.entities);
    let (metres_per_unit, unit_named) = match length_unit_mm(&entities) {
        Some(mm) if mm.is_finite() && mm > 0.0 => (mm * 1e-3, true),
        _ => (1e-3, false),
    };
    let table = catch_unwind(AssertUnwindSafe(|| Table::from_data_section(data)))
        .map_err(|p| parse(format!("its entities cannot be read: {}", panic_message(&*p))))?;
    let mut shells: Vec<(&u64, &ShellHolder)> = table.shell.iter().collect();
    shells.sort_by_key(|(id, _)| **id);
    if shells.is_empty() {
        return Err(CadError::Model {
            file: file.to_string(),
            reason: "no shell: the file has no B-rep faces (only wireframe, points or a mesh?)".to_string(),
        });
    }
    let mut faces = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for (&shell_id, shell) in shells {
        for place in &shell.cfs_faces {
            let face_id = match place {
                PlaceHolder::Ref(Name::Entity(id)) => *id,
                _ => shell_id,
            };
            if !seen.insert(face_id) {
                continue;
            }
            let face = read_face(&table, &entities, place, face_id, file, metres_per_unit, faces.len())?;
            faces.push(face);
        }
    }
    if faces.is_empty() {
        return Err(CadError::Model { file: file.to_string(), reason: "its shells hold no faces".to_string() });
    }
    Ok(Model { file: file.to_string(), metres_per_unit, unit_named, faces })
}

/// One face, converted and checked on its own.
fn read_face(
    table: &Table,
    entities: &EntityNames,
    place: &PlaceHolder<FaceAnyHolder>,
    face_id: u64,
    file: &str,
    scale: f64,
    index: usize,
) -> Result<StepFace, CadError> {
    let entity = |id: u64, reason: String| CadError::Entity { file: file.to_string(), id, entity: entities.name(id), reason };
    let (orientation, surface_face) =
        face_surface(table, place).ok_or_else(|| entity(face_id, "not a face this reader knows".to_string()))?;
    // The surface first, so that an unsupported one is named as such.
    let surface_id = match &surface_face.face_geometry {
        PlaceHolder::Ref(Name::Entity(id)) => *id,
        _ => face_id,
    };
    let converted = catch_unwind(AssertUnwindSafe(|| {
        let owned = surface_face.face_geometry.clone().into_owned(table).map_err(|e| e.to_string())?;
        truck_stepio::r#in::alias::Surface::try_from(&owned).map(|_| ()).map_err(|e| e.to_string())
    }));
    match converted {
        Ok(Ok(())) => {}
        Ok(Err(reason)) => return Err(entity(surface_id, format!("the surface of face #{face_id} cannot be used: {reason}"))),
        Err(p) => return Err(entity(surface_id, format!("the surface of face #{face_id} is malformed: {}", panic_message(&*p)))),
    }
    let single = ShellHolder { label: String::new(), cfs_faces: vec![place.clone()] };
    let shell: ReadShell = match catch_unwind(AssertUnwindSafe(|| table.to_compressed_shell(&single))) {
        Ok(Ok(s)) => s,
        Ok(Err(e)) => return Err(entity(face_id, e.to_string())),
        Err(p) => return Err(entity(face_id, format!("its geometry is malformed: {}", panic_message(&*p)))),
    };
    if shell.faces.len() != 1 {
        return Err(entity(face_id, "its geometry cannot be read".to_string()));
    }
    if shell.faces[0].boundaries.len() != surface_face.bounds.len() {
        return Err(entity(
            face_id,
            format!(
                "{} of its {} boundary loops cannot be read",
                surface_face.bounds.len() - shell.faces[0].boundaries.len(),
                surface_face.bounds.len()
            ),
        ));
    }
    check_loops(&shell).map_err(|reason| entity(face_id, reason))?;
    let name = surface_face.label.trim().to_string();
    catch_unwind(AssertUnwindSafe(|| StepFace::new(index, face_id, name, &shell, orientation, scale)))
        .map_err(|p| entity(face_id, format!("its geometry is malformed: {}", panic_message(&*p))))?
        .map_err(|reason| entity(face_id, reason))
}

/// The face's geometry and whether an `ORIENTED_FACE` turns it over (false).
fn face_surface(table: &Table, place: &PlaceHolder<FaceAnyHolder>) -> Option<(bool, FaceSurfaceHolder)> {
    let holder = match place {
        PlaceHolder::Owned(h) => h.clone(),
        PlaceHolder::Ref(Name::Entity(id)) => table
            .oriented_face
            .get(id)
            .cloned()
            .map(FaceAnyHolder::OrientedFace)
            .or_else(|| table.face_surface.get(id).cloned().map(FaceAnyHolder::FaceSurface))?,
        PlaceHolder::Ref(_) => return None,
    };
    match holder {
        FaceAnyHolder::FaceSurface(f) => Some((true, f)),
        FaceAnyHolder::OrientedFace(o) => {
            let inner = match &o.face_element {
                PlaceHolder::Ref(Name::Entity(id)) => table.face_surface.get(id).cloned()?,
                PlaceHolder::Owned(f) => f.clone(),
                PlaceHolder::Ref(_) => return None,
            };
            Some((o.orientation, inner))
        }
    }
}

/// Every loop's edges exist and meet end to end: an edge the reader dropped (an unsupported curve)
/// breaks a loop.
fn check_loops(shell: &ReadShell) -> Result<(), String> {
    for (k, wire) in shell.faces[0].boundaries.iter().enumerate() {
        if wire.is_empty() {
            return Err(format!("boundary loop {k} is empty (an edge curve of an unsupported type?)"));
        }
        let mut ends = Vec::with_capacity(wire.len());
        for e in wire {
            let edge = shell.edges.get(e.index).ok_or_else(|| format!("boundary loop {k} refers to an edge that cannot be read"))?;
            ends.push(if e.orientation { edge.vertices } else { (edge.vertices.1, edge.vertices.0) });
        }
        for i in 0..ends.len() {
            if ends[i].1 != ends[(i + 1) % ends.len()].0 {
                return Err(format!("boundary loop {k} is not closed (an edge of it cannot be read: an unsupported curve type?)"));
            }
        }
    }
    Ok(())
}

/// A panic's message.
fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>().map(|s| s.to_string()).or_else(|| p.downcast_ref::<String>().cloned()).unwrap_or_else(|| "a panic".to_string())
}

/// The file's entities by instance number: their records (a complex entity has several).
struct EntityNames<'a> {
    records: HashMap<u64, Vec<&'a Record>>,
}

impl<'a> EntityNames<'a> {
    fn of(entities: &'a [EntityInstance]) -> EntityNames<'a> {
        let records = entities
            .iter()
            .map(|e| match e {
                EntityInstance::Simple { id, record } => (*id, vec![record]),
                EntityInstance::Complex { id, subsuper } => (*id, subsuper.0.iter().collect()),
            })
            .collect();
        EntityNames { records }
    }

    /// The STEP type of `#id` (a complex entity's as `A+B`), or `missing` for a dangling reference.
    fn name(&self, id: u64) -> String {
        match self.records.get(&id) {
            Some(rs) => rs.iter().map(|r| r.name.as_str()).collect::<Vec<_>>().join("+"),
            None => "missing".to_string(),
        }
    }
}

/// Millimetres per length unit of the file, from its `GLOBAL_UNIT_ASSIGNED_CONTEXT`'s `LENGTH_UNIT`:
/// an `SI_UNIT(prefix, .METRE.)` or a `CONVERSION_BASED_UNIT` (inch, foot) over one. None if it names
/// none.
fn length_unit_mm(entities: &EntityNames) -> Option<f64> {
    fn args(r: &Record) -> &[Parameter] {
        match &r.parameter {
            Parameter::List(v) => v,
            _ => &[],
        }
    }
    fn real(p: &Parameter) -> Option<f64> {
        match p {
            Parameter::Real(x) => Some(*x),
            Parameter::Integer(i) => Some(*i as f64),
            Parameter::Typed { parameter, .. } => real(parameter),
            _ => None,
        }
    }
    fn unit_mm(entities: &EntityNames, id: u64, depth: u32) -> Option<f64> {
        let records = entities.records.get(&id)?;
        if depth > 8 {
            return None;
        }
        if let Some(si) = records.iter().find(|r| r.name == "SI_UNIT") {
            let a = args(si);
            let prefix = match a.first() {
                Some(Parameter::Enumeration(p)) => match p.as_str() {
                    "MILLI" => 1e-3,
                    "CENTI" => 1e-2,
                    "DECI" => 1e-1,
                    "KILO" => 1e3,
                    "MICRO" => 1e-6,
                    "NANO" => 1e-9,
                    _ => return None,
                },
                _ => 1.0,
            };
            return match a.get(1) {
                Some(Parameter::Enumeration(n)) if n == "METRE" => Some(prefix * 1000.0),
                _ => None,
            };
        }
        let converted = records.iter().find(|r| r.name == "CONVERSION_BASED_UNIT")?;
        let Parameter::Ref(Name::Entity(measure)) = args(converted).get(1)? else { return None };
        let with_unit = entities.records.get(measure)?.iter().find(|r| r.name.ends_with("MEASURE_WITH_UNIT"))?;
        let a = args(with_unit);
        let factor = real(a.first()?)?;
        let Parameter::Ref(Name::Entity(base)) = a.get(1)? else { return None };
        Some(factor * unit_mm(entities, *base, depth + 1)?)
    }
    let mut contexts: Vec<(&u64, &Vec<&Record>)> = entities.records.iter().collect();
    contexts.sort_by_key(|(id, _)| **id);
    for (_, records) in contexts {
        for r in records.iter().filter(|r| r.name == "GLOBAL_UNIT_ASSIGNED_CONTEXT") {
            let Some(Parameter::List(units)) = args(r).first() else { continue };
            for u in units {
                if let Parameter::Ref(Name::Entity(id)) = u
                    && entities.records.get(id).is_some_and(|rs| rs.iter().any(|r| r.name == "LENGTH_UNIT"))
                {
                    return unit_mm(entities, *id, 0);
                }
            }
        }
    }
    None
}
