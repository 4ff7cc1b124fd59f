//! Thread priorities: physics loops keep the default priority; render loops, the rayon pool
//! and the GPU driver's threads run under Linux's idle policy (`SCHED_IDLE`, and niced +10
//! where that policy is refused), so that when the cores are busy a frame comes late rather
//! than a physics step or a command acknowledgement; replays run there too (niced +19 where
//! refused). A niced thread only gets a smaller share: a physics thread waking every 2 ms
//! still waited behind it for the scheduler's granularity and missed steps with four M1
//! sessions on two cores. An idle-policy thread yields the core to any other at once.

/// The nice value of rendering threads.
pub const RENDER_NICE: i32 = 10;

/// The nice value of replay threads: below rendering, since a replay is batch work that may
/// take as long as it needs.
pub const REPLAY_NICE: i32 = 19;

/// Lowers the calling thread's priority to `nice` (Linux: per thread). Raising it needs
/// privileges and is not attempted. Returns whether it took effect.
pub fn lower_current_thread(nice: i32) -> bool {
    #[cfg(target_os = "linux")]
    {
        use thread_priority::unix::{
            NormalThreadSchedulePolicy, ThreadSchedulePolicy, set_thread_priority_and_policy,
            thread_native_id,
        };
        let tid = rustix::thread::gettid();
        let niced = rustix::process::setpriority_process(Some(tid), nice).is_ok();
        let idle = nice >= RENDER_NICE
            && set_thread_priority_and_policy(
                thread_native_id(),
                thread_priority::ThreadPriority::Min,
                ThreadSchedulePolicy::Normal(NormalThreadSchedulePolicy::Idle),
            )
            .is_ok();
        niced || idle
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = nice;
        false
    }
}

/// Builds rayon's global pool with niced workers (the CPU renderer, the detector model and
/// scene loading run there). Returns false if the pool already existed.
pub fn niced_rayon_pool() -> bool {
    rayon::ThreadPoolBuilder::new()
        .thread_name(|i| format!("render-pool-{i}"))
        .start_handler(|_| {
            lower_current_thread(RENDER_NICE);
        })
        .build_global()
        .is_ok()
}

/// Runs `make` on a niced thread and returns its result: threads it starts (a software GPU
/// driver's workers) inherit the priority.
pub fn on_niced_thread<T: Send + 'static>(make: impl FnOnce() -> T + Send + 'static) -> T {
    std::thread::spawn(move || {
        lower_current_thread(RENDER_NICE);
        make()
    })
    .join()
    .expect("the niced thread does not panic")
}
