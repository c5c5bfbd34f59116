//! Turning a segment into pieces: lines and arcs, the corner blends between lines within the
//! deviation tolerance (or 004's rules), kinks and their speed caps.

#[allow(clippy::wildcard_imports)]
use super::*;

impl PathEngine {
    /// Turns one segment into pieces, blending the corner from the previous line in lookahead mode.
    pub(super) fn append(&mut self, s: &Segment) {
        let start_point = self.tail.map_or(self.current_end_point(), |t| t.end);
        let axes_start = self.tail.map_or(self.pieces_end_axes(), |t| t.axes_end);
        let axes_end = s.axes.unwrap_or(axes_start);
        match s.kind {
            SegmentKind::Heat => {
                // A heat wait: a hold of no time that stays until released.
                self.tail = None;
                let piece = self.new_piece(Geometry::Hold { point: start_point }, 0.0, s, 0.0);
                let wait = s.heat.wait != HeatWait::None;
                let index = self.pieces.push(Piece { wait, axes: axes_start, ..piece });
                self.path_end = self.pieces.get(index).end();
                self.mark_dirty(index);
            }
            SegmentKind::Dwell => {
                self.tail = None;
                let piece = self.new_piece(Geometry::Hold { point: start_point }, 0.0, s, 0.0);
                let axes_delta = difference(&axes_end, &axes_start);
                let hold_time = s.duration.max(self.axes_step_time(&axes_delta));
                let index = self.pieces.push(Piece { hold_time, hold_filament: s.filament, axes: axes_start, axes_delta, ..piece });
                self.path_end = self.pieces.get(index).end();
                self.mark_dirty(index);
            }
            SegmentKind::Line | SegmentKind::Arc => {
                let (geometry, length, direction_in, direction_out) = if s.kind == SegmentKind::Line {
                    let delta = s.end - start_point;
                    let length = delta.norm();
                    let direction = delta / length;
                    (Geometry::Line { start: start_point, direction }, length, direction, direction)
                } else {
                    let geometry = arc_geometry(&start_point, s).unwrap_or(Geometry::Line { start: start_point, direction: Vector3::x() });
                    let length = geometry.length(0.0);
                    let d_in = geometry.point(0.0, length).tangent.normalize();
                    let d_out = geometry.point(length, length).tangent.normalize();
                    (geometry, length, d_in, d_out)
                };
                let flow = if s.extrudes() || s.filament != 0.0 { s.filament / length } else { 0.0 };
                let q_start = self.tail.map_or(self.pieces_end_orientation(), |t| t.q_end);
                let zeta = s.feed * s.feed / (self.config.max_acceleration * length);
                let mut junction_cap = f64::INFINITY;
                let mut trimmed_start = 0.0;
                let mut piece_geometry = geometry;
                let mut piece_length = length;
                if let Some(tail) = self.tail {
                    let turn = angle_between(&tail.direction_out, &direction_in);
                    match self.config.mode {
                        PlanningMode::StopAndGo => junction_cap = 0.0,
                        PlanningMode::KnowledgeRules => {
                            if !self.knowledge_rules_pass(&tail, zeta, turn) {
                                junction_cap = 0.0;
                            }
                        }
                        PlanningMode::Lookahead => {
                            if turn < STRAIGHT {
                            } else if tail.kind == SegmentKind::Line && s.kind == SegmentKind::Line && turn < std::f64::consts::PI - 1e-6 {
                                match self.blend(&tail, s, length, direction_in, turn) {
                                    Some(trim) => {
                                        trimmed_start = trim;
                                        piece_geometry =
                                            Geometry::Line { start: start_point + direction_in * trim, direction: direction_in };
                                        piece_length = length - trim;
                                    }
                                    None => junction_cap = self.kink_cap(turn),
                                }
                            } else {
                                junction_cap = self.kink_cap(turn);
                            }
                        }
                    }
                } else if self.pieces.len() > 0 || self.state.v > 0.0 {
                    // After a dwell or from an unknown direction: start from rest.
                    junction_cap = 0.0;
                }
                let mut piece = self.new_piece(piece_geometry, piece_length, s, flow);
                piece.junction_cap = junction_cap;
                piece.geometric_cap = self.centripetal_cap(geometry.min_radius());
                let q_trim = slerp_along(&q_start, &s.orientation, trimmed_start / length);
                piece.orientation = q_trim;
                piece.rotation = geom::quaternion_log(&(s.orientation * q_trim.inverse()));
                piece.axes = lerp(&axes_start, &axes_end, trimmed_start / length);
                piece.axes_delta = difference(&axes_end, &piece.axes);
                piece.geometric_cap = piece.geometric_cap.min(self.axes_speed_cap(&piece));
                // The axes' rate along the path before this piece: the blend's just appended, else the
                // tail segment's (its last piece may be trimmed to nothing), else none (from rest).
                let before = if trimmed_start > 0.0 {
                    Some(piece_rate(self.pieces.get(self.pieces.tail - 1)))
                } else {
                    self.tail.map(|t| tail_rate(&t))
                };
                if let Some(before) = before {
                    piece.junction_cap = piece.junction_cap.min(self.axes_junction_cap(&before, &piece_rate(&piece)));
                }
                let index = self.pieces.push(piece);
                self.path_end = self.pieces.get(self.pieces.tail - 1).end();
                self.mark_dirty(self.tail.map_or(index, |t| t.piece).min(index));
                let zeta_previous = self.tail.map_or(0.0, |t| t.zeta);
                self.tail = Some(Tail {
                    piece: index,
                    kind: s.kind,
                    end: s.end,
                    direction_out,
                    length,
                    trimmed_start,
                    q_start,
                    q_end: s.orientation,
                    axes_start,
                    axes_end,
                    zeta,
                    zeta_previous,
                    feed: s.feed,
                });
            }
        }
    }

    pub(super) fn new_piece(&self, geometry: Geometry, length: f64, s: &Segment, flow: f64) -> Piece {
        let start = if self.pieces.len() > 0 { self.pieces.get(self.pieces.tail - 1).end() } else { self.state.s };
        Piece {
            start,
            length,
            feed: s.feed,
            geometric_cap: self.config.max_speed,
            flow,
            seq: s.seq,
            source_line: s.source_line,
            flags: s.flags,
            pressure_advance: s.pressure_advance,
            ..Piece::new(geometry, s.orientation)
        }
    }

    pub(super) fn current_end_point(&self) -> Vector3<f64> {
        if self.pieces.len() > 0 {
            let p = self.pieces.get(self.pieces.tail - 1);
            p.geometry.end(p.length)
        } else {
            self.sample_geometry().position
        }
    }

    /// The external axes at the end of the last piece (where the next one starts).
    pub(super) fn pieces_end_axes(&self) -> [f64; MAX_EXTERNAL_AXES] {
        if self.pieces.len() > 0 {
            let p = self.pieces.get(self.pieces.tail - 1);
            sum(&p.axes, &p.axes_delta)
        } else {
            self.last_piece_axes
        }
    }

    /// The speed cap (m/s) that keeps every external axis within [`AXIS_SPEED_SHARE`] of its
    /// speed limit over a line or arc piece (its rate along the path times the path speed).
    pub(super) fn axes_speed_cap(&self, p: &Piece) -> f64 {
        let mut cap = f64::INFINITY;
        if p.length > 0.0 {
            for (limit, delta) in self.axis_limits[..self.axis_count].iter().zip(p.axes_delta) {
                let rate = delta.abs() / p.length;
                if rate > 0.0 {
                    cap = cap.min(AXIS_SPEED_SHARE * limit.velocity / rate);
                }
            }
        }
        cap
    }

    /// The speed cap (m/s) at a junction where the external axes' rates along the path (rad/m or
    /// m/m) change from `before` to `after`: each axis's speed steps by at most half a tick of its
    /// acceleration (the other half is the path's own slowing or speeding up in that tick).
    pub(super) fn axes_junction_cap(&self, before: &[f64; MAX_EXTERNAL_AXES], after: &[f64; MAX_EXTERNAL_AXES]) -> f64 {
        let mut cap = f64::INFINITY;
        for (i, limit) in self.axis_limits[..self.axis_count].iter().enumerate() {
            let step = (after[i] - before[i]).abs();
            if step > 0.0 {
                cap = cap.min(0.5 * limit.acceleration * self.dt / step);
            }
        }
        cap
    }

    /// How long (s) the smooth step 10τ³ − 15τ⁴ + 6τ⁵ must take to move the external axes by
    /// `delta` within their limits: its peak speed is 1.875·Δ/T, its peak acceleration
    /// 10/√3·Δ/T², its peak jerk 60·Δ/T³.
    pub(super) fn axes_step_time(&self, delta: &[f64; MAX_EXTERNAL_AXES]) -> f64 {
        let mut t: f64 = 0.0;
        for (limit, d) in self.axis_limits[..self.axis_count].iter().zip(delta) {
            let d = d.abs();
            if d > 0.0 {
                t = t
                    .max(1.875 * d / limit.velocity)
                    .max((10.0 / 3f64.sqrt() * d / limit.acceleration).sqrt())
                    .max(libm::cbrt(60.0 * d / limit.jerk));
            }
        }
        // Whole ticks, at least one: the step is sampled at the tick rate.
        if t > 0.0 { (t / self.dt).ceil().max(1.0) * self.dt } else { 0.0 }
    }

    pub(super) fn pieces_end_orientation(&self) -> UnitQuaternion<f64> {
        if self.pieces.len() > 0 {
            let p = self.pieces.get(self.pieces.tail - 1);
            geom::quaternion_exp(&p.rotation) * p.orientation
        } else {
            self.last_piece_orientation
        }
    }

    /// 004 Table I: does the tool pass from the tail segment s_i into the new one s_{i+1} at speed?
    /// Phases (1) and (2) continue; (3), (1)+(3) and segments no rule covers stop at the end.
    pub(super) fn knowledge_rules_pass(&self, tail: &Tail, zeta_next: f64, turn: f64) -> bool {
        let cos_phi = libm::cos(turn);
        let eps = self.config.corner_cosine;
        let (z_prev, z_i, z_next) = (tail.zeta_previous, tail.zeta, zeta_next);
        // Rule (1): a curve starts at s_i (phase (1) if it goes on, (1)+(3) if it turns sharply).
        let rule_1 = z_prev < 1.0 && z_i > 1.0 && z_next > 1.0;
        // Rule (2): inside a curve (phase (2), or (3) at a sharp turn).
        let rule_2 = z_prev > 1.0 && z_i > 1.0 && z_next > 1.0;
        // Rule (3) and long segments come to rest (normal planning).
        (rule_1 || rule_2) && cos_phi >= eps
    }

    /// The speed at a kink that cannot be blended: tiny kinks at speed, larger ones slowly.
    /// The speed cap (m/s) on a curve of `radius` (m): the centripetal limit, planned at
    /// [`CENTRIPETAL_PLANNING_SHARE`] of it, and `max_speed`.
    pub(super) fn centripetal_cap(&self, radius: f64) -> f64 {
        self.config.max_speed.min((CENTRIPETAL_PLANNING_SHARE * self.config.centripetal_acceleration * radius).sqrt())
    }

    pub(super) fn kink_cap(&self, turn: f64) -> f64 {
        if turn <= self.config.max_kink { f64::INFINITY } else { self.config.centripetal_acceleration * self.dt / turn }
    }

    /// Blends the corner between the tail line and a new line with a tangent arc that stays within
    /// the deviation tolerance and uses at most half of the new line. Trims the tail piece and
    /// appends the arc; returns the length trimmed from the new line, or None if no blend fits.
    pub(super) fn blend(&mut self, tail: &Tail, s: &Segment, length: f64, direction_in: Vector3<f64>, turn: f64) -> Option<f64> {
        let half = 0.5 * turn;
        let (tan_half, cos_half) = (libm::tan(half), libm::cos(half));
        let tolerance = self.config.deviation_tolerance;
        // Deviation of the arc midpoint from the corner: r (1/cos(φ/2) − 1).
        let r_tolerance = tolerance * cos_half / (1.0 - cos_half);
        let available_tail = tail.length - tail.trimmed_start;
        let mut d = (r_tolerance * tan_half).min(available_tail).min(0.5 * length);
        // The tail piece may already be under way: keep the blend beyond where the tool could stop.
        let tail_piece = *self.pieces.get(tail.piece);
        let stop = self.state.s + self.braking.stopping_distance(self.state.v, self.state.a);
        d = d.min(tail_piece.end() - stop);
        if d < 1e-7 {
            return None;
        }
        let radius = d / tan_half;
        let corner = tail.end;
        let p_in = corner - tail.direction_out * d;
        let bisector = (direction_in - tail.direction_out).normalize();
        let centre = corner + bisector * (radius / cos_half);
        let e1 = (p_in - centre).normalize();
        let normal = e1.cross(&tail.direction_out).normalize();
        let e2 = normal.cross(&e1);
        let geometry = Geometry::Arc { centre, e1, e2, normal, radius, radius_rate: 0.0, pitch: 0.0, sweep: turn };
        let arc_length = radius * turn;
        // Trim the tail piece.
        {
            let tp = self.pieces.get_mut(tail.piece);
            tp.length = (tp.length - d).max(0.0);
            let rotation_fraction =
                if tail.length - tail.trimmed_start > 0.0 { tp.length / (tail.length - tail.trimmed_start) } else { 1.0 };
            tp.rotation *= rotation_fraction;
            for d in tp.axes_delta.iter_mut() {
                *d *= rotation_fraction;
            }
        }
        let q_in = slerp_along(&tail.q_start, &tail.q_end, (tail.length - d) / tail.length);
        let q_out = slerp_along(&tail.q_end, &s.orientation, d / length);
        let blend_start = self.pieces.get(tail.piece).end();
        let mut arc = self.new_piece(geometry, arc_length, s, 0.0);
        arc.start = blend_start;
        arc.feed = tail.feed.min(s.feed);
        arc.geometric_cap = self.centripetal_cap(radius);
        // Each half of the blend keeps its own segment's filament per metre, so the bead keeps its
        // cross-section; the blend is shorter than the two trimmed ends, by (1 − φ/(2 tan(φ/2))).
        arc.flow = if s.extrudes() || s.filament != 0.0 { s.filament / length } else { 0.0 };
        arc.split = 0.5;
        arc.first = (tail_piece.seq, tail_piece.source_line, tail_piece.flags, tail_piece.flow);
        arc.orientation = q_in;
        arc.rotation = geom::quaternion_log(&(q_out * q_in.inverse()));
        let s_axes = s.axes.unwrap_or(tail.axes_end);
        arc.axes = lerp(&tail.axes_start, &tail.axes_end, (tail.length - d) / tail.length);
        arc.axes_delta = difference(&lerp(&tail.axes_end, &s_axes, d / length), &arc.axes);
        arc.geometric_cap = arc.geometric_cap.min(self.axes_speed_cap(&arc));
        arc.junction_cap = arc.junction_cap.min(self.axes_junction_cap(&tail_rate(tail), &piece_rate(&arc)));
        self.pieces.push(arc);
        self.stats.blends += 1;
        Some(d)
    }
}

/// a − b, entry by entry.
pub(super) fn difference(a: &[f64; MAX_EXTERNAL_AXES], b: &[f64; MAX_EXTERNAL_AXES]) -> [f64; MAX_EXTERNAL_AXES] {
    std::array::from_fn(|i| a[i] - b[i])
}

/// a + b, entry by entry.
pub(super) fn sum(a: &[f64; MAX_EXTERNAL_AXES], b: &[f64; MAX_EXTERNAL_AXES]) -> [f64; MAX_EXTERNAL_AXES] {
    std::array::from_fn(|i| a[i] + b[i])
}

/// a + (b − a)·u, entry by entry.
pub(super) fn lerp(a: &[f64; MAX_EXTERNAL_AXES], b: &[f64; MAX_EXTERNAL_AXES], u: f64) -> [f64; MAX_EXTERNAL_AXES] {
    std::array::from_fn(|i| a[i] + (b[i] - a[i]) * u)
}

/// The external axes' rates along a line or arc piece (rad/m or m/m; 0 on a hold).
pub(super) fn piece_rate(p: &Piece) -> [f64; MAX_EXTERNAL_AXES] {
    std::array::from_fn(|i| if p.length > 0.0 { p.axes_delta[i] / p.length } else { 0.0 })
}

/// The external axes' rates along the tail segment as a whole (rad/m or m/m).
fn tail_rate(t: &Tail) -> [f64; MAX_EXTERNAL_AXES] {
    std::array::from_fn(|i| if t.length > 0.0 { (t.axes_end[i] - t.axes_start[i]) / t.length } else { 0.0 })
}
