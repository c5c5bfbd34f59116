//! The lookahead: segments from the intake queue become pieces in the ring (the blends are in
//! [`super::blend`]), and the backward pass keeps every boundary's cap, speed and potential (the
//! module doc of [`super`] says why they are safe).

#[allow(clippy::wildcard_imports)]
use super::*;

impl PathEngine {
    pub(super) fn refresh_cap(&mut self, k: u64) {
        let over = self.feed_override;
        let max_speed = self.config.max_speed;
        let previous_cap = if k > self.pieces.head { Some(piece_cap(self.pieces.get(k - 1), over, max_speed)) } else { None };
        let p = self.pieces.get_mut(k);
        let own = piece_cap(p, over, max_speed);
        let mut vcap = p.junction_cap.min(own);
        if let Some(prev) = previous_cap {
            vcap = vcap.min(prev);
        }
        if p.is_hold() {
            vcap = 0.0;
        }
        p.vcap = vcap;
    }

    pub(super) fn mark_dirty(&mut self, from: u64) {
        self.dirty_from = Some(self.dirty_from.map_or(from, |d| d.min(from)));
    }

    /// Updates `vb` and the later minimum of the potential from the end back, stopping where
    /// nothing changes any more or beyond one braking distance of the change. Returns the work done.
    pub(super) fn backward_pass(&mut self) -> usize {
        let Some(changed) = self.dirty_from.take() else { return 0 };
        let horizon = self.braking.w(self.config.max_speed) + 1e-6;
        let end = self.pieces.tail;
        let change_position = if changed < end { self.pieces.get(changed).start } else { self.path_end };
        let mut later_min = self.braking.potential(self.path_end, 0.0);
        let mut later_arg = end;
        let mut work = 0;
        let mut k = end;
        while k > self.pieces.head {
            k -= 1;
            work += 1;
            self.refresh_cap(k);
            let braking = self.braking;
            let p = self.pieces.get_mut(k);
            let unchanged = p.later_min == later_min && p.later_arg == later_arg;
            // Two plans make a speed at this boundary safe: slowing to the next boundary's vb
            // within this piece (exact, arriving at zero acceleration), or one continuous braking
            // curve to the boundary holding the later minimum (the composable bound). Either will
            // do; the executor follows the one that allows more.
            let next_vb = if k + 1 < end { self.pieces.get(k + 1).vb } else { 0.0 };
            let p = self.pieces.get(k);
            let hop = hop_speed(&braking, p, next_vb);
            let chain = braking.w_inverse(later_min - p.start);
            let vb = p.vcap.min(hop.max(chain));
            let via_chain = chain > hop;
            let p = self.pieces.get_mut(k);
            p.via_chain = via_chain;
            let potential = braking.potential(p.start, vb);
            // Below a boundary whose speed did not change, sits at its cap, and whose later
            // minimum only rose, every stored value is still safe (at worst slower than it could
            // be), so the pass can stop there: this keeps appending to a long run of tiny segments
            // cheap, where the end's potential is the later minimum of every boundary.
            let saturated_and_relaxed = p.vb == vb && vb == p.vcap && later_min >= p.later_min;
            let unchanged = (unchanged && p.vb == vb && p.potential == potential) || saturated_and_relaxed;
            p.later_min = later_min;
            p.later_arg = later_arg;
            p.vb = vb;
            p.potential = potential;
            let start = p.start;
            if potential <= later_min {
                later_min = potential;
                later_arg = k;
            }
            if k < changed && (unchanged || change_position - start > horizon) {
                break;
            }
        }
        self.stats.plan_work += work as u64;
        work
    }

    /// Moves segments from the intake queue into the lookahead within the tick's budget.
    pub(super) fn plan(&mut self) {
        // One segment's pass is atomic (it is bounded by the pieces within one braking distance of
        // the change); the budget decides how many segments are taken in per tick.
        let mut budget = self.config.plan_budget;
        while budget > 0 && self.intake.len() > 0 && self.pieces.room() >= 4 {
            let Some(segment) = self.intake.pop() else { break };
            self.append(&segment);
            self.replan = true;
            budget = budget.saturating_sub(self.backward_pass().max(1));
        }
    }
}

/// Length (m) the backward pass keeps in hand when it slows from one boundary to the next within a
/// piece. Without it the boundary speed sits exactly on the edge of feasibility (the bisection of
/// [`Braking::reach`] finds it to the last ulp), and the executor's position-interface plan over
/// the piece, a degenerate problem there, comes out a hair too long or not at all.
pub(super) fn hop_margin(length: f64) -> f64 {
    1e-9 + 1e-6 * length
}

/// The highest speed (m/s) at the start of piece `p`, arriving at zero acceleration, from which the
/// tool still slows to `next_vb` within the piece (less [`hop_margin`]): the exact "hop" of the
/// backward pass, and the executor's bound on a too-fast arrival.
pub(super) fn hop_speed(braking: &Braking, p: &Piece, next_vb: f64) -> f64 {
    braking.reach(p.length - hop_margin(p.length), next_vb, p.vcap)
}

/// The speed cap inside a piece (m/s): feed × override, the geometric cap.
pub(super) fn piece_cap(p: &Piece, feed_override: f64, max_speed: f64) -> f64 {
    if p.is_hold() { 0.0 } else { (p.feed * feed_override).min(p.geometric_cap).min(max_speed) }
}
