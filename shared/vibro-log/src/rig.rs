//! The rig packetizer: a rig's (or the simulator's) sample streams as wire messages.
//! [`Packetizer`] cuts chunks of samples into [`VibBlock`]s, [`AccelBlock`]s and the
//! matching [`TruthBlock`]s, with sequence numbers and sample indices continuous over
//! the run; `vibrocomp sim` (MCAP or live) feeds it the simulator's chunks, and the CSV
//! import ([`crate::import`]) follows the same rules.
//!
//! The packetizer takes plain slices ([`RigChunk`], [`TruthSample`]), so that it knows
//! no simulator: the caller hands over what its chunk holds.
//!
//! Times are the producer's, from the run start: a generated log is a function of
//! the scenario and seed only (bit-identical across runs). A live publisher stamps
//! `publish_ns` with its clock when it sends.

use vibro_msgs::{
    accel_flags, truth_flags, AccelBlock, TruthBlock, VibBlock, ACCEL_BLOCK_MAX, VIB_BLOCK_MAX,
};

/// One chunk of a run: whole accelerometer output intervals and the vibration-sensor
/// samples inside (what `vibro_sim::SimChunk` holds, as slices).
#[derive(Debug, Clone, Copy)]
pub struct RigChunk<'a> {
    /// Index (in the whole run) of the chunk's first vibration-sensor sample.
    pub sensor_first_index: u64,
    /// Vibration-sensor samples, V: channel `u` is the sensor of unit `u`.
    pub sensor_v: &'a [[f64; 3]],
    /// Index (in the whole run) of the chunk's first accelerometer output sample.
    pub output_first_index: u64,
    /// Accelerometer outputs, V, per unit.
    pub accel_v: &'a [[f64; 3]],
}

/// The truth of one accelerometer output sample along each unit's input axis (IA), as
/// a [`TruthBlock`] carries it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TruthSample {
    /// Flight acceleration along each unit's IA, g.
    pub a_l_ia_g: [f64; 3],
    /// Mean over the output interval of the whole acceleration each unit senses along
    /// its IA (flight plus vibration), g.
    pub a_sensed_ia_g: [f64; 3],
    /// The exact vibration error of each unit, g.
    pub vib_error_ia_g: [f64; 3],
}

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

    /// Feeds one chunk, with the truth of its accelerometer output samples in order (a
    /// sample without truth leaves the truth block's slot as it was); `emit` receives
    /// each block as it fills (sensor blocks of the chunk first, then the
    /// accelerometer and truth blocks).
    pub fn push_chunk<E>(
        &mut self,
        chunk: RigChunk<'_>,
        truth: impl IntoIterator<Item = TruthSample>,
        mut emit: impl FnMut(RigMessage<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        for (k, row) in chunk.sensor_v.iter().enumerate() {
            if self.vib.count == 0 {
                let index = chunk.sensor_first_index + k as u64;
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
        let mut truth = truth.into_iter();
        for (k, row) in chunk.accel_v.iter().enumerate() {
            if self.accel.count == 0 {
                let index = chunk.output_first_index + k as u64;
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
            if let Some(t) = truth.next() {
                self.truth.a_l_ia_g[i] = t.a_l_ia_g;
                self.truth.a_sensed_ia_g[i] = t.a_sensed_ia_g;
                self.truth.vib_error_ia_g[i] = t.vib_error_ia_g;
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Blocks cut across chunks: continuous sequence numbers and sample indices, times
    /// on the rates' grids (an accelerometer block stamped with the end of its first
    /// interval, a message with its last sample), the truth beside each accelerometer
    /// sample, and a gap between chunks flagged on the next block.
    #[test]
    fn blocks_follow_the_samples_across_chunks_and_gaps() {
        // 1 kHz sensor, 100 Hz output: 4-sample vibration and 2-sample accel blocks.
        let mut p = Packetizer::new(1000.0, 100.0, 4, 2, 7);
        let sensor: Vec<[f64; 3]> = (0..8).map(|k| [k as f64, 0.0, 0.0]).collect();
        let accel: Vec<[f64; 3]> = (0..2).map(|k| [0.0, k as f64, 0.0]).collect();
        let truth = |k: usize| TruthSample {
            a_l_ia_g: [k as f64; 3],
            a_sensed_ia_g: [1.0; 3],
            vib_error_ia_g: [1e-6 * k as f64; 3],
        };
        type Head = (char, u64, u64, u64, u32, u32, u64);
        let mut got: Vec<Head> = Vec::new();
        let mut truths = Vec::new();
        let mut emit = |m: RigMessage<'_>| -> Result<(), ()> {
            let t = m.time_ns();
            match m {
                RigMessage::Vib(b) => {
                    assert_eq!((b.source_id, b.sample_period_ns), (7, 1_000_000));
                    got.push((
                        'v',
                        b.seq,
                        b.first_sample_index,
                        b.t0_ns,
                        b.count,
                        b.flags,
                        t,
                    ))
                }
                RigMessage::Accel(b) => got.push((
                    'a',
                    b.seq,
                    b.first_sample_index,
                    b.t0_ns,
                    b.count,
                    b.flags,
                    t,
                )),
                RigMessage::Truth(b) => {
                    truths.push((b.seq, b.t0_ns, b.flags, b.a_l_ia_g[..2].to_vec()))
                }
            }
            Ok(())
        };
        let first = RigChunk {
            sensor_first_index: 0,
            sensor_v: &sensor,
            output_first_index: 0,
            accel_v: &accel,
        };
        p.push_chunk(first, (0..2).map(truth), &mut emit).unwrap();
        // The next chunk starts 4 sensor samples and 1 output sample late.
        let second = RigChunk {
            sensor_first_index: 12,
            sensor_v: &sensor[..4],
            output_first_index: 3,
            accel_v: &accel,
        };
        p.push_chunk(second, (3..5).map(truth), &mut emit).unwrap();
        p.flush(&mut emit).unwrap();
        let gap_v = vibro_msgs::vib_flags::GAP_BEFORE;
        let gap_a = accel_flags::GAP_BEFORE;
        assert_eq!(
            got,
            [
                ('v', 0, 0, 0, 4, 0, 3_000_000),
                ('v', 1, 4, 4_000_000, 4, 0, 7_000_000),
                ('a', 0, 0, 10_000_000, 2, 0, 20_000_000),
                ('v', 2, 12, 12_000_000, 4, gap_v, 15_000_000),
                ('a', 1, 3, 40_000_000, 2, gap_a, 50_000_000),
            ]
        );
        assert_eq!(p.blocks(), (3, 2));
        let known = truth_flags::VIB_ERROR_KNOWN;
        assert_eq!(
            truths,
            [
                (0, 10_000_000, known, vec![[0.0; 3], [1.0; 3]]),
                (
                    1,
                    40_000_000,
                    known | truth_flags::GAP_BEFORE,
                    vec![[3.0; 3], [4.0; 3]]
                ),
            ]
        );
    }
}
