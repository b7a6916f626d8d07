//! Background work: the pose solves of the vision frames, in thread mode, preempted by the control loop.
//!
//! The step (in the SysTick exception) queues a frame with its capture-time attitude
//! (`flight_core::SolveJob`); [`hand_over_jobs`] moves it into [`JOBS`]; thread mode ([`run`]) takes it,
//! solves it with `flight_core::solve_job` outside any critical section and puts the outcome into [`SOLVED`];
//! the next step's [`deliver_solved`] hands it to the flight stack, which fuses it. Only the hand-overs (a copy
//! of a job or an outcome, about 150 bytes) are critical sections, so a solve of up to 2.5 ms never delays a
//! tick. When thread mode falls behind, the oldest frame waiting is given up and counted, as the flight
//! stack's own queues do (`VisionCounters::dropped`).
use crate::board;
use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use cortex_m::interrupt::Mutex;
use flight_core::{FlightStack, FrameOutcome, SOLVE_QUEUE, SolveJob, VisionConfig};
use heapless::Deque;

/// Frames waiting for their solve.
static JOBS: Mutex<RefCell<Deque<SolveJob, SOLVE_QUEUE>>> = Mutex::new(RefCell::new(Deque::new()));
/// Solved frames waiting for the next step: capture time and outcome.
static SOLVED: Mutex<RefCell<Deque<(u64, FrameOutcome), SOLVE_QUEUE>>> =
    Mutex::new(RefCell::new(Deque::new()));
/// Frames given up in these two queues since the last step (counted into the flight stack's counters there).
static DROPPED: AtomicU32 = AtomicU32::new(0);
/// The pose solve's configuration (the flight stack's, copied at start and when an upload replaces it), and
/// how many times it was set (a solve begun under an earlier one is not handed to the new stack).
static VISION: Mutex<RefCell<Option<(VisionConfig, u32)>>> = Mutex::new(RefCell::new(None));

/// Sets the configuration the solves use, and gives up the frames waiting or solved under the one before
/// (their attitudes and the estimator they belong to are gone with the stack they came from).
pub fn set_vision(vision: VisionConfig) {
    cortex_m::interrupt::free(|cs| {
        let mut v = VISION.borrow(cs).borrow_mut();
        let epoch = v.map_or(0, |(_, e)| e.wrapping_add(1));
        *v = Some((vision, epoch));
        JOBS.borrow(cs).borrow_mut().clear();
        SOLVED.borrow(cs).borrow_mut().clear();
    });
    DROPPED.store(0, Ordering::Relaxed);
}

/// Frames solved.
pub static SOLVES: AtomicU32 = AtomicU32::new(0);
/// Whether thread mode is inside a solve (for [`TICKS_DURING_SOLVES`]).
static SOLVING: AtomicBool = AtomicBool::new(false);
/// Ticks whose exception preempted a solve, and of them those that ran a control step (counted by the control
/// loop, [`note_tick`]).
pub static TICKS_DURING_SOLVES: AtomicU32 = AtomicU32::new(0);
/// See [`TICKS_DURING_SOLVES`].
pub static STEPS_DURING_SOLVES: AtomicU32 = AtomicU32::new(0);

/// Counts a tick that preempted a solve (control loop); `step`: the tick runs a control step.
pub fn note_tick(step: bool) {
    if SOLVING.load(Ordering::Acquire) {
        TICKS_DURING_SOLVES.fetch_add(1, Ordering::Relaxed);
        if step {
            STEPS_DURING_SOLVES.fetch_add(1, Ordering::Relaxed);
        }
    }
}
/// The longest solve from start to end, preemptions by the control loop included (cycles).
pub static SOLVE_CYCLES_MAX: AtomicU32 = AtomicU32::new(0);

/// Moves the jobs the step queued into [`JOBS`] (control loop).
pub fn hand_over_jobs(stack: &mut FlightStack) {
    while let Some(job) = stack.take_job() {
        cortex_m::interrupt::free(|cs| {
            let mut q = JOBS.borrow(cs).borrow_mut();
            if q.is_full() {
                q.pop_front();
                DROPPED.fetch_add(1, Ordering::Relaxed);
            }
            // Cannot fail: a place was made above.
            let _ = q.push_back(job);
        });
    }
}

/// Hands the frames solved since the previous step to the flight stack, oldest first (control loop).
pub fn deliver_solved(stack: &mut FlightStack) {
    while let Some((t, outcome)) = cortex_m::interrupt::free(|cs| SOLVED.borrow(cs).borrow_mut().pop_front())
    {
        stack.deliver(t, outcome);
    }
    for _ in 0..DROPPED.swap(0, Ordering::Relaxed) {
        stack.count_dropped_frame();
    }
}

/// Thread mode: solves the frames as they come, sleeping while there are none. Never returns.
pub fn run() -> ! {
    loop {
        // Take a job (with the configuration to solve it with), or sleep until an interrupt: the check and the
        // `wfi` in one critical section, so that a job handed over between them leaves its SysTick pending,
        // which ends the `wfi`.
        let work = cortex_m::interrupt::free(|cs| {
            let vision = *VISION.borrow(cs).borrow();
            let job = vision.and_then(|_| JOBS.borrow(cs).borrow_mut().pop_front());
            if job.is_none() {
                cortex_m::asm::wfi();
            }
            job.zip(vision)
        });
        let Some((job, (vision, epoch))) = work else { continue };
        let t0 = board::cycles();
        SOLVING.store(true, Ordering::Release);
        let outcome = flight_core::solve_job(&job, &vision);
        SOLVING.store(false, Ordering::Release);
        let cycles = board::cycles_since(t0);
        cortex_m::interrupt::free(|cs| {
            if VISION.borrow(cs).borrow().is_none_or(|(_, e)| e != epoch) {
                return;
            }
            let mut q = SOLVED.borrow(cs).borrow_mut();
            if q.is_full() {
                q.pop_front();
                DROPPED.fetch_add(1, Ordering::Relaxed);
            }
            // Cannot fail: a place was made above.
            let _ = q.push_back((job.measurement.capture_time_us, outcome));
        });
        SOLVES.fetch_add(1, Ordering::Relaxed);
        SOLVE_CYCLES_MAX.fetch_max(cycles, Ordering::Relaxed);
    }
}
