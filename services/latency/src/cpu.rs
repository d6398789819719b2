//! CPU accounting: a process's user + system time from `/proc/PID/stat` ([`Cpu`]),
//! the machine's busy time from `/proc/stat` ([`MachineCpu`]), and this process's
//! and its waited-for children's from `getrusage` ([`rusage_cpu_s`]).

use std::time::Instant;

/// utime + stime of process `pid`, clock ticks; `None` once it is gone.
fn cpu_ticks(pid: u32) -> Option<u64> {
    stat_ticks(&std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?)
}

/// utime + stime of a `/proc/PID/stat` line, clock ticks.
fn stat_ticks(stat: &str) -> Option<u64> {
    // Fields after the command name (which may hold spaces): state is field 3.
    let rest = stat.get(stat.rfind(')')? + 2..)?;
    let f: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of the whole line: 12 and 13 here.
    Some(f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?)
}

/// Clock ticks per second (`_SC_CLK_TCK`, 100 where unknown).
fn ticks_per_s() -> f64 {
    // SAFETY: sysconf has no preconditions.
    let t = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if t > 0 {
        t as f64
    } else {
        100.0
    }
}

/// Processes' CPU use from a start: `finish` gives each one's percent of one core.
pub(crate) struct Cpu {
    pids: Vec<(String, u32, u64)>,
    start: Instant,
}

impl Cpu {
    pub(crate) fn start(pids: &[(&str, u32)]) -> Self {
        Self {
            pids: pids
                .iter()
                .map(|&(n, p)| (n.to_string(), p, cpu_ticks(p).unwrap_or(0)))
                .collect(),
            start: Instant::now(),
        }
    }

    pub(crate) fn finish(&self) -> Vec<(String, f64)> {
        let wall = self.start.elapsed().as_secs_f64().max(1e-9);
        self.pids
            .iter()
            .map(|(n, p, t0)| {
                let t = cpu_ticks(*p).unwrap_or(*t0).saturating_sub(*t0);
                (n.clone(), 100.0 * t as f64 / ticks_per_s() / wall)
            })
            .collect()
    }
}

/// The machine's CPU time (`/proc/stat`, all cores): busy and total ticks.
pub(crate) struct MachineCpu(Option<(u64, u64)>);

impl MachineCpu {
    fn read() -> Option<(u64, u64)> {
        Self::parse(&std::fs::read_to_string("/proc/stat").ok()?)
    }

    /// (busy, total) ticks of the `cpu ` line of a `/proc/stat`.
    fn parse(stat: &str) -> Option<(u64, u64)> {
        let line = stat.lines().find(|l| l.starts_with("cpu "))?;
        let f: Vec<u64> = line
            .split_whitespace()
            .skip(1)
            .filter_map(|x| x.parse().ok())
            .collect();
        // user nice system idle iowait irq softirq steal ...: idle and iowait are idle.
        let total: u64 = f.iter().take(8).sum();
        let idle = f.get(3)? + f.get(4).copied().unwrap_or(0);
        Some((total - idle, total))
    }

    pub(crate) fn now() -> Self {
        Self(Self::read())
    }

    pub(crate) fn busy_percent_since(&self) -> f64 {
        match (self.0, Self::read()) {
            (Some((b0, t0)), Some((b1, t1))) if t1 > t0 => {
                100.0 * (b1 - b0) as f64 / (t1 - t0) as f64
            }
            _ => 0.0,
        }
    }
}

/// CPU seconds (user + system) of this process, and of its children that were waited
/// for.
pub(crate) fn rusage_cpu_s() -> f64 {
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    let mut total = 0.0;
    for who in [libc::RUSAGE_SELF, libc::RUSAGE_CHILDREN] {
        // SAFETY: getrusage writes one rusage into the zeroed struct we own.
        let mut u: libc::rusage = unsafe { std::mem::zeroed() };
        if unsafe { libc::getrusage(who, &mut u) } == 0 {
            total += tv(u.ru_utime) + tv(u.ru_stime);
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stat_ticks_are_utime_plus_stime_after_the_command_name() {
        // The command name holds spaces and parentheses; utime (field 14) = 250,
        // stime (field 15) = 50.
        let stat = "1234 (my (odd) cmd) S 1 1234 1234 0 -1 4194560 100 0 0 0 250 50 0 0 20 0 1 0";
        assert_eq!(stat_ticks(stat), Some(300));
        assert_eq!(stat_ticks("1234 (cmd)"), None);
        assert_eq!(stat_ticks("1234 (cmd) S 1 2 3"), None);
        assert_eq!(stat_ticks("no parenthesis"), None);
    }

    #[test]
    fn this_process_has_cpu_ticks() {
        assert!(cpu_ticks(std::process::id()).is_some());
        assert!(ticks_per_s() > 0.0);
    }

    #[test]
    fn machine_cpu_busy_is_all_but_idle_and_iowait() {
        // user nice system idle iowait irq softirq steal guest guest_nice: the first 8
        // are the total (621), idle + iowait (450) are not busy (171); guest time is
        // already in user.
        let stat = "cpu  100 20 30 400 50 6 7 8 9 10\ncpu0 50 10 15 200 25 3 3 4 4 5\nintr 1\n";
        assert_eq!(MachineCpu::parse(stat), Some((171, 621)));
        assert_eq!(MachineCpu::parse("cpu0 1 2 3 4\n"), None);
        assert_eq!(MachineCpu::parse("cpu  1 2 3\n"), None);
    }
}
