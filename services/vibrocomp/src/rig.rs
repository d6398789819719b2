//! The simulated rig's streams as wire messages: cuts the simulator's chunks into
//! [`VibBlock`]s, [`AccelBlock`]s and the matching [`TruthBlock`]s, with sequence
//! numbers and sample indices continuous over the run. Used by `sim` (MCAP or live),
//! `demo` and `latency`.
//!
//! Times are the simulation's, from the run start: a generated log is a function of
//! the scenario and seed only (bit-identical across runs). A live publisher stamps
//! `publish_ns` with its clock when it sends.

use vibro_msgs::{
    accel_flags, truth_flags, AccelBlock, TruthBlock, VibBlock, ACCEL_BLOCK_MAX, VIB_BLOCK_MAX,
};
use vibro_sim::SimChunk;

/// One message of the rig, borrowed from the packetizer until the next call.
#[derive(Debug, Clone, Copy)]
pub enum RigMessage<'a> {
    Vib(&'a VibBlock),
    Accel(&'a AccelBlock),
    Truth(&'a TruthBlock),
}

impl RigMessage<'_> {
    /// The producer's time of the message: the time of its last sample, ns.
    pub fn time_ns(&self) -> u64 {
        match self {
            RigMessage::Vib(b) => {
                b.t0_ns + u64::from(b.count.saturating_sub(1)) * b.sample_period_ns
            }
            RigMessage::Accel(b) => {
                b.t0_ns + u64::from(b.count.saturating_sub(1)) * b.sample_period_ns
            }
            RigMessage::Truth(b) => {
                b.t0_ns + u64::from(b.count.saturating_sub(1)) * b.sample_period_ns
            }
        }
    }
}

/// Cuts chunks into blocks. Buffers are allocated once (boxed: a `VibBlock` is 12 kB).
pub struct Packetizer {
    vib: Box<VibBlock>,
    accel: Box<AccelBlock>,
    truth: Box<TruthBlock>,
    vib_per_block: usize,
    accel_per_block: usize,
    sensor_period_ns: f64,
    output_period_ns: f64,
    vib_next_index: u64,
    accel_next_index: u64,
}

impl Packetizer {
    /// A packetizer for a run at the given sensor and output rates, with blocks of at
    /// most `vib_per_block` and `accel_per_block` samples (clamped to the wire limits).
    pub fn new(
        sensor_hz: f64,
        output_hz: f64,
        vib_per_block: usize,
        accel_per_block: usize,
        source_id: u32,
    ) -> Self {
        let mut vib = Box::new(VibBlock::ZEROED);
        let mut accel = Box::new(AccelBlock::ZEROED);
        let mut truth = Box::new(TruthBlock::ZEROED);
        let sensor_period_ns = 1e9 / sensor_hz;
        let output_period_ns = 1e9 / output_hz;
        vib.sample_period_ns = sensor_period_ns.round() as u64;
        vib.source_id = source_id;
        accel.sample_period_ns = output_period_ns.round() as u64;
        accel.source_id = source_id;
        truth.sample_period_ns = accel.sample_period_ns;
        truth.source_id = source_id;
        Self {
            vib,
            accel,
            truth,
            vib_per_block: vib_per_block.clamp(1, VIB_BLOCK_MAX),
            accel_per_block: accel_per_block.clamp(1, ACCEL_BLOCK_MAX),
            sensor_period_ns,
            output_period_ns,
            vib_next_index: 0,
            accel_next_index: 0,
        }
    }

    /// Blocks sent so far: `(vib, accel)`.
    pub fn blocks(&self) -> (u64, u64) {
        (self.vib.seq, self.accel.seq)
    }

    /// Feeds one chunk; `emit` receives each block as it fills (sensor blocks of the
    /// chunk first, then the accelerometer and truth blocks).
    pub fn push_chunk<E>(
        &mut self,
        chunk: &SimChunk,
        mut emit: impl FnMut(RigMessage<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        for (k, row) in chunk.sensor_v().iter().enumerate() {
            if self.vib.count == 0 {
                let index = chunk.sensor_first_index() + k as u64;
                self.vib.first_sample_index = index;
                self.vib.t0_ns = (index as f64 * self.sensor_period_ns).round() as u64;
                self.vib.flags = if index == self.vib_next_index {
                    0
                } else {
                    vibro_msgs::vib_flags::GAP_BEFORE
                };
            }
            self.vib.sample_v[self.vib.count as usize] = *row;
            self.vib.count += 1;
            if self.vib.count as usize == self.vib_per_block {
                self.emit_vib(&mut emit)?;
            }
        }
        let truth = chunk.truth();
        for (k, row) in chunk.accel_v().iter().enumerate() {
            if self.accel.count == 0 {
                let index = chunk.output_first_index() + k as u64;
                let end_ns = ((index + 1) as f64 * self.output_period_ns).round() as u64;
                let gap = index != self.accel_next_index;
                self.accel.first_sample_index = index;
                self.accel.t0_ns = end_ns;
                self.accel.flags = if gap { accel_flags::GAP_BEFORE } else { 0 };
                self.truth.first_sample_index = index;
                self.truth.t0_ns = end_ns;
                self.truth.flags =
                    truth_flags::VIB_ERROR_KNOWN | if gap { truth_flags::GAP_BEFORE } else { 0 };
            }
            let i = self.accel.count as usize;
            self.accel.output_v[i] = *row;
            if let Some(t) = truth.get(k) {
                self.truth.a_l_ia_g[i] =
                    [t.a_l_unit_g[0][2], t.a_l_unit_g[1][2], t.a_l_unit_g[2][2]];
                self.truth.a_sensed_ia_g[i] = [
                    t.a_mean_unit_g[0][2],
                    t.a_mean_unit_g[1][2],
                    t.a_mean_unit_g[2][2],
                ];
                self.truth.vib_error_ia_g[i] = t.exact_ve_g;
            }
            self.accel.count += 1;
            self.truth.count += 1;
            if self.accel.count as usize == self.accel_per_block {
                self.emit_accel(&mut emit)?;
            }
        }
        Ok(())
    }

    /// Sends the partly filled blocks left at the end of a run.
    pub fn flush<E>(
        &mut self,
        mut emit: impl FnMut(RigMessage<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        if self.vib.count > 0 {
            self.emit_vib(&mut emit)?;
        }
        if self.accel.count > 0 {
            self.emit_accel(&mut emit)?;
        }
        Ok(())
    }

    fn emit_vib<E>(
        &mut self,
        emit: &mut impl FnMut(RigMessage<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        let n = self.vib.count as usize;
        // Unused slots are zero, so equal runs give equal bytes.
        self.vib.sample_v[n..].fill([0.0; 3]);
        self.vib.publish_ns = RigMessage::Vib(&self.vib).time_ns();
        emit(RigMessage::Vib(&self.vib))?;
        self.vib_next_index = self.vib.first_sample_index + n as u64;
        self.vib.seq += 1;
        self.vib.count = 0;
        Ok(())
    }

    fn emit_accel<E>(
        &mut self,
        emit: &mut impl FnMut(RigMessage<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        let n = self.accel.count as usize;
        self.accel.output_v[n..].fill([0.0; 3]);
        self.truth.a_l_ia_g[n..].fill([0.0; 3]);
        self.truth.a_sensed_ia_g[n..].fill([0.0; 3]);
        self.truth.vib_error_ia_g[n..].fill([0.0; 3]);
        self.accel.publish_ns = RigMessage::Accel(&self.accel).time_ns();
        self.truth.publish_ns = self.accel.publish_ns;
        self.truth.seq = self.accel.seq;
        emit(RigMessage::Accel(&self.accel))?;
        emit(RigMessage::Truth(&self.truth))?;
        self.accel_next_index = self.accel.first_sample_index + n as u64;
        self.accel.seq += 1;
        self.accel.count = 0;
        self.truth.count = 0;
        Ok(())
    }
}
