//! Real-time set-up of the pipeline's threads: core pinning (`core_affinity`), `SCHED_FIFO`
//! (`thread-priority`) and locked memory (`mlockall`), each when permitted. What could not be
//! had is reported as one line ([`RtStatus::notes`]) and the pipeline goes on without it.

use thread_priority::{
    set_thread_priority_and_policy, thread_native_id, RealtimeThreadSchedulePolicy, ThreadPriority,
    ThreadPriorityValue, ThreadSchedulePolicy,
};

/// What a thread's set-up obtained.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct ThreadRt {
    /// Thread name.
    pub name: String,
    /// Core it is pinned to.
    pub core: Option<usize>,
    /// `SCHED_FIFO` granted (and its priority), or why not (`None`: not asked).
    pub fifo: Option<Result<u8, String>>,
}

/// What the whole pipeline obtained.
#[derive(Debug, Clone, PartialEq, Eq, Default, serde::Serialize)]
pub struct RtStatus {
    /// Memory locked (`mlockall(MCL_CURRENT | MCL_FUTURE)`), or why not (`None`: not asked).
    pub mlock: Option<Result<(), String>>,
    /// Per thread.
    pub threads: Vec<ThreadRt>,
}

impl RtStatus {
    /// One line per thing asked for and not obtained.
    pub fn notes(&self) -> Vec<String> {
        let mut v = Vec::new();
        if let Some(Err(e)) = &self.mlock {
            v.push(format!(
                "note: memory not locked (mlockall: {e}); page faults may add latency"
            ));
        }
        for t in &self.threads {
            if let Some(Err(e)) = &t.fifo {
                v.push(format!(
                    "note: SCHED_FIFO not permitted for the {} thread ({e}); it runs at normal \
                     priority",
                    t.name
                ));
            }
            if t.core.is_none() {
                v.push(format!(
                    "note: the {} thread is not pinned to a core",
                    t.name
                ));
            }
        }
        v
    }

    /// One line saying what was granted.
    pub fn summary(&self) -> String {
        let fifo: Vec<String> = self
            .threads
            .iter()
            .map(|t| {
                format!(
                    "{} on core {} {}",
                    t.name,
                    t.core.map_or("-".to_string(), |c| c.to_string()),
                    match t.fifo {
                        Some(Ok(p)) => format!("SCHED_FIFO {p}"),
                        _ => "normal priority".to_string(),
                    }
                )
            })
            .collect();
        let mlock = match &self.mlock {
            None => "memory not locked (not asked)",
            Some(Ok(())) => "memory locked",
            Some(Err(_)) => "memory not locked (not permitted)",
        };
        format!("{}; {mlock}", fifo.join(", "))
    }
}

/// Locks the process's memory, current and future (`mlockall`).
pub fn lock_memory() -> Result<(), String> {
    // SAFETY: mlockall takes flags only and touches no memory of ours.
    let r = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error().to_string())
    }
}

/// The calling thread's CPU time, ns (`CLOCK_THREAD_CPUTIME_ID`): the work the thread did,
/// without the time the OS gave to other threads and processes (0 if the clock is refused).
/// A clock for the core's stage timings when worst cases are compared on a shared machine.
pub fn thread_cpu_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec, which `ts` is, and keeps no pointer to it.
    let r = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    if r != 0 {
        return 0;
    }
    let s = u64::try_from(ts.tv_sec).unwrap_or(0);
    let ns = u64::try_from(ts.tv_nsec).unwrap_or(0);
    s.saturating_mul(1_000_000_000).saturating_add(ns)
}

/// Undoes [`lock_memory`] (the pipeline's end).
pub fn unlock_memory() {
    // SAFETY: munlockall takes no arguments and touches no memory of ours.
    unsafe {
        libc::munlockall();
    }
}

/// Pins the calling thread to the `index`-th core the process may use (modulo their number)
/// and, when `fifo` is set, asks for `SCHED_FIFO` at `priority` (1-99 on Linux).
pub fn setup_current_thread(name: &str, index: usize, fifo: Option<u8>) -> ThreadRt {
    let core = core_affinity::get_core_ids()
        .filter(|ids| !ids.is_empty())
        .and_then(|ids| {
            let id = ids[index % ids.len()];
            core_affinity::set_for_current(id).then_some(id.id)
        });
    let fifo = fifo.map(|p| set_fifo(p).map(|()| p));
    ThreadRt {
        name: name.to_string(),
        core,
        fifo,
    }
}

fn set_fifo(priority: u8) -> Result<(), String> {
    let value = ThreadPriorityValue::try_from(priority).map_err(|e| e.to_string())?;
    set_thread_priority_and_policy(
        thread_native_id(),
        ThreadPriority::Crossplatform(value),
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    )
    .map_err(|e| match e {
        thread_priority::Error::OS(code) => {
            format!("{}", std::io::Error::from_raw_os_error(code))
        }
        other => other.to_string(),
    })
}
