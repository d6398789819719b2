//! The peers of the baselines and of the soak's load, each a `latency-peer ...`
//! child process of the `vibrocomp` executable: their command line ([`PeerCommand`],
//! parsed by the CLI's hidden `latency-peer` command), their loops ([`run_peer`]),
//! and how the rig starts and stops them ([`spawn_peer`], [`KillOnDrop`]).

use anyhow::{bail, Context};
use std::io::{Read, Write};
use std::os::unix::net::UnixListener;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use vibro_ipc::{create_node, create_waitset, now_ns, StreamPublisher, StreamSubscriber};
use vibro_msgs::{
    AccelBlock, CompensatedBlock, Heartbeat, ServiceId, ServiceNames, Stream, VibBlock, VibEstimate,
};
use vibro_service::{LoopMode, ServiceConfig};

use crate::hosts;
use crate::load::peer_load;

// Defined here, beside `spawn_peer` and the other places that write these arguments,
// so that the command line a peer is started with and the one it parses stay one.
/// The hidden peers of the baselines.
#[derive(Debug, Clone, clap::Subcommand)]
pub enum PeerCommand {
    /// Answers every accelerometer block on `{prefix}accel` with a compensated block
    /// holding its timestamps, nothing computed.
    Bare {
        /// Service-name prefix of the streams.
        #[arg(long)]
        prefix: String,
        /// Loop mode: event or spin.
        #[arg(long, default_value = "event")]
        mode: LoopMode,
    },
    /// Takes every vibration block on `{prefix}vib` and drops it: the estimator's
    /// process without the estimation, so that the bare pipeline moves both streams.
    BareVib {
        /// Service-name prefix of the streams.
        #[arg(long)]
        prefix: String,
        /// Loop mode: event or spin.
        #[arg(long, default_value = "event")]
        mode: LoopMode,
    },
    /// The bare Zenoh baseline's peer (`--hosts 2`): connects to ENDPOINT, answers
    /// every accelerometer block on `{key}/accel` on `{key}/compensated` with its
    /// timestamps, takes the vibration blocks on `{key}/vib`; until SIGTERM.
    BareZenoh {
        /// The rig's Zenoh endpoint (`tcp/127.0.0.1:PORT`).
        #[arg(long)]
        endpoint: String,
        /// The key prefix.
        #[arg(long)]
        key: String,
    },
    /// The estimator's and the compensator's logic over two Unix stream sockets in DIR.
    Uds {
        /// The folder of the two Unix sockets.
        #[arg(long = "socket-dir")]
        socket_dir: PathBuf,
        /// The estimator's configuration [default: its default one].
        #[arg(long = "estimator-config")]
        estimator_config: Option<PathBuf>,
    },
    /// The soak's background load: runs `vibrocomp lab diagnose INPUT` again and again,
    /// JOBS at a time, until SIGTERM; then kills the runs under way and prints
    /// `{"runs_started", "runs_completed", "failures", "first_failure", "cpu_s",
    /// "wall_s"}` on stdout (`cpu_s`: its own and its waited-for runs' CPU).
    /// Stops at the first failed run.
    Load {
        /// The campaign table or log `lab diagnose` runs on.
        #[arg(long)]
        input: PathBuf,
        /// Runs at a time.
        #[arg(long, default_value_t = 1)]
        jobs: u32,
    },
}

/// Runs the peer `cmd` in this process, until its input ends or SIGTERM.
pub fn run_peer(cmd: &PeerCommand) -> anyhow::Result<()> {
    match cmd {
        PeerCommand::Bare { prefix, mode } => peer_bare(prefix, *mode),
        PeerCommand::BareVib { prefix, mode } => peer_bare_vib(prefix, *mode),
        PeerCommand::BareZenoh { endpoint, key } => {
            hosts::peer_bare_zenoh(endpoint, key, install_stop()?)
        }
        PeerCommand::Uds {
            socket_dir,
            estimator_config,
        } => peer_uds(socket_dir, estimator_config.as_deref()),
        PeerCommand::Load { input, jobs } => peer_load(input, *jobs),
    }
}

/// This executable's `latency-peer` with `args`, its stderr appended to `log`
/// (`what`: how an error names it).
pub(crate) fn spawn_peer<S: AsRef<std::ffi::OsStr>>(
    args: &[S],
    log: &Path,
    what: &str,
) -> anyhow::Result<std::process::Child> {
    std::process::Command::new(std::env::current_exe()?)
        .arg("latency-peer")
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(vibro_files::open_append(log)?)
        .spawn()
        .with_context(|| format!("starting {what}"))
}

/// A peer killed (SIGTERM, then SIGKILL after 3 s) when dropped.
pub(crate) struct KillOnDrop<'a>(pub(crate) Option<&'a mut std::process::Child>);
impl KillOnDrop<'_> {
    pub(crate) fn pid(&self) -> u32 {
        self.0.as_ref().map_or(0, |c| c.id())
    }
}
impl Drop for KillOnDrop<'_> {
    fn drop(&mut self) {
        if let Some(c) = self.0.take() {
            vibro_service::supervise::terminate(c);
            let t = Instant::now();
            while t.elapsed() < Duration::from_secs(3) {
                if let Ok(Some(_)) = c.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// The loop of a bare peer, the services' loop structure without their work: wait on
/// `input` (WaitSet or spin), hand every message to `take`, and publish a heartbeat as
/// `service` every 0.2 s (with `received` = what `take` returned last).
fn bare_peer_loop<T: iceoryx2::prelude::ZeroCopySend + std::fmt::Debug + 'static>(
    names: &ServiceNames,
    node: &vibro_ipc::IpcNode,
    input: Stream,
    service: ServiceId,
    mode: LoopMode,
    mut take: impl FnMut(&T) -> u64,
) -> anyhow::Result<()> {
    let sub = StreamSubscriber::<T>::open(node, names, input)?;
    let mut heartbeat =
        StreamPublisher::<Heartbeat>::open(node, names, Stream::Heartbeat(service))?;
    let waitset = create_waitset()?;
    let _g = waitset
        .attach_notification(sub.listener())
        .map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let stop = install_stop()?;
    let (mut next_hb, mut received) = (0u64, 0u64);
    while !stop.load(Ordering::Acquire) {
        if mode == LoopMode::Event {
            waitset
                .wait_and_process_once_with_timeout(
                    |_| iceoryx2::prelude::CallbackProgression::Continue,
                    Duration::from_millis(100),
                )
                .map_err(|e| anyhow::anyhow!("wait: {e:?}"))?;
            let _ = sub.clear_events();
        }
        let mut any = false;
        while let Some(m) = sub.receive()? {
            any = true;
            received = take(&m);
        }
        if mode == LoopMode::Spin {
            if any {
                let _ = sub.clear_events();
            } else {
                std::hint::spin_loop();
            }
        }
        let now = now_ns();
        if now >= next_hb {
            next_hb = now + 200_000_000;
            let _ = heartbeat.publish(&Heartbeat {
                publish_ns: now,
                received,
                service: service.code(),
                state: vibro_msgs::ServiceState::Running.code(),
                ..Heartbeat::ZEROED
            });
        }
    }
    Ok(())
}

/// The bare forwarder: the compensator's loop without the compensation.
fn peer_bare(prefix: &str, mode: LoopMode) -> anyhow::Result<()> {
    let names = ServiceNames::new(prefix)?;
    let node = create_node("vibrocomp-bare")?;
    let mut out = StreamPublisher::<CompensatedBlock>::open(&node, &names, Stream::Compensated)?;
    let mut seq = 0u64;
    bare_peer_loop(
        &names,
        &node,
        Stream::Accel,
        ServiceId::Compensator,
        mode,
        |b: &AccelBlock| {
            let recv_ns = now_ns();
            let _ = out.publish_with(|m| {
                m.seq = seq;
                m.input_seq = b.seq;
                m.first_sample_index = b.first_sample_index;
                m.t0_ns = b.t0_ns;
                m.sample_period_ns = b.sample_period_ns;
                m.input_publish_ns = b.publish_ns;
                m.recv_ns = recv_ns;
                m.count = b.count;
                m.publish_ns = now_ns();
            });
            seq += 1;
            seq
        },
    )
}

/// The bare vibration sink: the estimator's loop without the estimation.
fn peer_bare_vib(prefix: &str, mode: LoopMode) -> anyhow::Result<()> {
    let names = ServiceNames::new(prefix)?;
    let node = create_node("vibrocomp-bare-vib")?;
    let mut taken = 0u64;
    bare_peer_loop(
        &names,
        &node,
        Stream::Vib,
        ServiceId::Estimator,
        mode,
        |_: &VibBlock| {
            taken += 1;
            taken
        },
    )
}

/// SIGTERM/SIGINT set the returned flag (the peers have no tokio runtime).
pub(crate) fn install_stop() -> anyhow::Result<Arc<AtomicBool>> {
    static STOP: AtomicBool = AtomicBool::new(false);
    extern "C" fn on_signal(_: libc::c_int) {
        STOP.store(true, Ordering::Release);
    }
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
    }
    let flag = Arc::new(AtomicBool::new(false));
    let f = Arc::clone(&flag);
    std::thread::spawn(move || {
        while !STOP.load(Ordering::Acquire) {
            std::thread::sleep(Duration::from_millis(20));
        }
        f.store(true, Ordering::Release);
    });
    Ok(flag)
}

/// The socket peer's estimates, sent to its compensator thread: stamped as the
/// service's publisher stamps them (after the estimate is written).
struct EstimateChannel(std::sync::mpsc::Sender<VibEstimate>);

impl vibro_estimator::EstimateSink for EstimateChannel {
    fn publish_with(
        &mut self,
        fill: impl FnOnce(&mut VibEstimate),
    ) -> (u64, vibro_ipc::Result<usize>) {
        let mut m = VibEstimate::ZEROED;
        fill(&mut m);
        let publish_ns = now_ns();
        m.publish_ns = publish_ns;
        // The compensator thread gone: the run is ending.
        let _ = self.0.send(m);
        (publish_ns, Ok(1))
    }
}

/// The socket peer: the estimator's and compensator's logic on two threads.
fn peer_uds(dir: &Path, estimator_config: Option<&Path>) -> anyhow::Result<()> {
    let est_config = match estimator_config {
        Some(p) => <vibro_estimator::Config as ServiceConfig>::load(p)?,
        None => vibro_estimator::Config::load_default()?,
    };
    let comp_config = vibro_compensator::Config::load_default()?;
    let vib_path = dir.join("vib.sock");
    let accel_path = dir.join("accel.sock");
    let _ = std::fs::remove_file(&vib_path);
    let _ = std::fs::remove_file(&accel_path);
    let vib_listener =
        UnixListener::bind(&vib_path).with_context(|| format!("{}", vib_path.display()))?;
    let accel_listener =
        UnixListener::bind(&accel_path).with_context(|| format!("{}", accel_path.display()))?;
    let (tx, rx) = std::sync::mpsc::channel::<VibEstimate>();
    let estimator = std::thread::spawn(move || -> anyhow::Result<()> {
        let (mut sock, _) = vib_listener.accept()?;
        let mut est = vibro_estimator::InProcess::new(&est_config.estimator)?;
        let mut estimates = EstimateChannel(tx);
        let mut buf = vec![0u8; std::mem::size_of::<VibBlock>()];
        loop {
            if sock.read_exact(&mut buf).is_err() {
                return Ok(());
            }
            let recv_ns = now_ns();
            let Some(b) = VibBlock::from_bytes(&buf) else {
                bail!("vib block size")
            };
            est.on_block(&b, recv_ns, &mut estimates)?;
        }
    });
    let (mut sock, _) = accel_listener.accept()?;
    let mut writer = sock.try_clone()?;
    let mut comp = vibro_compensator::InProcess::new(&comp_config)?;
    let mut buf = vec![0u8; std::mem::size_of::<AccelBlock>()];
    let mut out = Vec::with_capacity(4);
    loop {
        if sock.read_exact(&mut buf).is_err() {
            break;
        }
        let recv_ns = now_ns();
        let Some(b) = AccelBlock::from_bytes(&buf) else {
            bail!("accel block size")
        };
        while let Ok(e) = rx.try_recv() {
            comp.on_estimate(&e);
        }
        out.clear();
        comp.on_accel(&b, recv_ns, &mut out);
        for m in &out {
            writer.write_all(m.as_bytes())?;
        }
    }
    let _ = writer.shutdown(std::net::Shutdown::Both);
    let _ = estimator.join();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Peer {
        #[command(subcommand)]
        cmd: PeerCommand,
    }

    fn parse(args: &[&str]) -> PeerCommand {
        Peer::try_parse_from(std::iter::once("latency-peer").chain(args.iter().copied()))
            .unwrap()
            .cmd
    }

    #[test]
    fn the_arguments_the_rig_writes_parse_back() {
        match parse(&["bare", "--prefix", "vcbare-1/", "--mode", "spin"]) {
            PeerCommand::Bare { prefix, mode } => {
                assert_eq!((prefix.as_str(), mode), ("vcbare-1/", LoopMode::Spin))
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(
            parse(&["bare-vib", "--prefix", "p/"]),
            PeerCommand::BareVib {
                mode: LoopMode::Event,
                ..
            }
        ));
        assert!(matches!(
            parse(&["bare-zenoh", "--endpoint", "tcp/127.0.0.1:1", "--key", "k"]),
            PeerCommand::BareZenoh { .. }
        ));
        match parse(&[
            "uds",
            "--socket-dir",
            "/tmp/d",
            "--estimator-config",
            "e.toml",
        ]) {
            PeerCommand::Uds {
                socket_dir,
                estimator_config,
            } => {
                assert_eq!(socket_dir, PathBuf::from("/tmp/d"));
                assert_eq!(estimator_config, Some(PathBuf::from("e.toml")));
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(
            parse(&["load", "--input", "c.csv", "--jobs", "3"]),
            PeerCommand::Load { jobs: 3, .. }
        ));
    }
}
