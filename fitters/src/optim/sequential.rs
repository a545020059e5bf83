//! Adapter that turns a sequential, closure-style algorithm into an ask/tell [`Optimizer`].
//!
//! The algorithm is a `FnOnce(&mut dyn FnMut(&[f64]) -> Option<f64>)`: it calls the evaluator
//! for each point it wants and gets `Some(value)` back, or `None` when the run is aborted
//! (then it must return promptly).  It runs on its own thread; points and values travel over
//! two bounded channels, so exactly one point is outstanding at a time and the sequence of
//! asks is deterministic.
//!
//! When the algorithm returns (converged) the adapter restarts it from the best point seen,
//! with `scale · 10^−(k mod 3)` on restart `k` (lfit choice: alternately refine and re-explore),
//! so the budget is always usable.  If the algorithm keeps returning without asking anything
//! (three times in a row), the adapter asks Gaussian perturbations of the best point instead.
//!
//! Dropping the adapter closes both channels, which turns every pending or future evaluation
//! into `None`, then joins the thread: no thread is leaked or left blocked.

use std::sync::mpsc::{self, Receiver, SyncSender};
use std::thread::{self, JoinHandle};

use super::util::{self, OptRng};
use super::{Bounds, Optimizer, Problem};

/// The evaluator handed to a sequential algorithm.
pub type Evaluator<'a> = dyn FnMut(&[f64]) -> Option<f64> + 'a;

/// A sequential algorithm run to completion (or abort) on the adapter's thread.
pub type SeqAlgorithm = Box<dyn FnOnce(&mut Evaluator<'_>) + Send + 'static>;

/// Makes the algorithm for a run: `(start, scale, run index)`; run 0 is the first run.
pub type SeqFactory = Box<dyn FnMut(&[f64], &[f64], usize) -> SeqAlgorithm + Send + 'static>;

/// Restart scale factor for run `k` (k ≥ 1): `10^−(k mod 3)`.
pub fn restart_factor(k: usize) -> f64 {
    10f64.powi(-((k % 3) as i32))
}

/// Consecutive runs that asked nothing before the fallback sampler takes over.
pub const MAX_EMPTY_RUNS: usize = 3;

struct Worker {
    points: Receiver<Vec<f64>>,
    values: SyncSender<Option<f64>>,
    handle: Option<JoinHandle<()>>,
}

impl Worker {
    fn spawn(algo: SeqAlgorithm) -> Option<Worker> {
        let (ptx, prx) = mpsc::sync_channel::<Vec<f64>>(1);
        let (vtx, vrx) = mpsc::sync_channel::<Option<f64>>(1);
        let handle = thread::Builder::new()
            .name("lfit-optim-seq".to_string())
            .spawn(move || {
                let mut aborted = false;
                let mut eval = |x: &[f64]| -> Option<f64> {
                    if aborted {
                        return None;
                    }
                    if ptx.send(x.to_vec()).is_err() {
                        aborted = true;
                        return None;
                    }
                    match vrx.recv() {
                        Ok(Some(v)) => Some(v),
                        _ => {
                            aborted = true;
                            None
                        }
                    }
                };
                algo(&mut eval);
            })
            .ok()?;
        Some(Worker {
            points: prx,
            values: vtx,
            handle: Some(handle),
        })
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        // Replace the channel ends with dead ones so the worker sees disconnection, then join.
        let (dead_tx, _) = mpsc::sync_channel::<Option<f64>>(1);
        let (_, dead_rx) = mpsc::sync_channel::<Vec<f64>>(1);
        drop(std::mem::replace(&mut self.values, dead_tx));
        drop(std::mem::replace(&mut self.points, dead_rx));
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// Ask/tell adapter around a sequential algorithm (see the module docs).
pub struct Sequential {
    name: String,
    bounds: Bounds,
    scale: Vec<f64>,
    factory: SeqFactory,
    worker: Option<Worker>,
    pending: Option<Vec<f64>>,
    pending_fallback: bool,
    best_x: Vec<f64>,
    best_f: f64,
    runs: usize,
    empty_runs: usize,
    asked_in_run: usize,
    rng: OptRng,
}

impl Sequential {
    /// Adapter named `name`; run 0 starts at `problem.start` with `problem.scale`.
    pub fn new(name: &str, problem: &Problem, factory: SeqFactory, seed: u64) -> Self {
        Self::starting_at(
            name,
            problem,
            problem.start.clone(),
            problem.scale.clone(),
            factory,
            seed,
        )
    }

    /// Adapter whose first run starts at `start` with `scale` (both clipped/sanitised).
    pub fn starting_at(
        name: &str,
        problem: &Problem,
        mut start: Vec<f64>,
        scale: Vec<f64>,
        factory: SeqFactory,
        seed: u64,
    ) -> Self {
        start.resize(problem.dim(), 0.0);
        problem.bounds.clip(&mut start);
        let scale: Vec<f64> = (0..problem.dim())
            .map(|j| match scale.get(j) {
                Some(&s) if s.is_finite() && s > 0.0 => s,
                _ => problem.scale[j],
            })
            .collect();
        Sequential {
            name: name.to_string(),
            bounds: problem.bounds.clone(),
            scale,
            factory,
            worker: None,
            pending: None,
            pending_fallback: false,
            best_x: start,
            best_f: f64::INFINITY,
            runs: 0,
            empty_runs: 0,
            asked_in_run: 0,
            rng: util::rng(seed),
        }
    }

    /// Number of runs started so far (1 + restarts).
    pub fn runs(&self) -> usize {
        self.runs
    }

    /// Best point told so far and its value.
    pub fn best(&self) -> (&[f64], f64) {
        (&self.best_x, self.best_f)
    }

    fn start_run(&mut self) {
        let k = self.runs;
        let f = if k == 0 { 1.0 } else { restart_factor(k) };
        let scale: Vec<f64> = self.scale.iter().map(|s| s * f).collect();
        let algo = (self.factory)(&self.best_x, &scale, k);
        self.runs += 1;
        self.asked_in_run = 0;
        self.worker = Worker::spawn(algo);
    }

    fn fallback_point(&mut self) -> Vec<f64> {
        let mut x: Vec<f64> = self
            .best_x
            .iter()
            .zip(&self.scale)
            .map(|(&b, &s)| b + 0.1 * s * util::normal(&mut self.rng))
            .collect();
        self.bounds.clip(&mut x);
        x
    }
}

impl Optimizer for Sequential {
    fn name(&self) -> &str {
        &self.name
    }

    fn ask(&mut self, _max: usize) -> Vec<Vec<f64>> {
        if let Some(p) = &self.pending {
            return vec![p.clone()];
        }
        loop {
            if self.empty_runs >= MAX_EMPTY_RUNS {
                let x = self.fallback_point();
                self.pending = Some(x.clone());
                self.pending_fallback = true;
                return vec![x];
            }
            if self.worker.is_none() {
                self.start_run();
            }
            let next = self.worker.as_ref().and_then(|w| w.points.recv().ok());
            match next {
                Some(mut x) => {
                    x.resize(self.bounds.dim(), 0.0);
                    self.bounds.clip(&mut x);
                    self.asked_in_run += 1;
                    self.empty_runs = 0;
                    self.pending = Some(x.clone());
                    self.pending_fallback = false;
                    return vec![x];
                }
                None => {
                    // The run finished (or could not start): restart from the best point.
                    if let Some(w) = self.worker.take() {
                        drop(w);
                    }
                    if self.asked_in_run == 0 {
                        self.empty_runs += 1;
                    }
                }
            }
        }
    }

    fn tell(&mut self, xs: &[Vec<f64>], values: &[f64]) {
        // Without a value the pending point stays pending (it is asked again).
        let Some(&v) = values.first() else { return };
        let Some(x) = self.pending.take() else { return };
        let _ = xs;
        let v = util::sanitize(v);
        if v < self.best_f {
            self.best_f = v;
            self.best_x.clone_from(&x);
        }
        if self.pending_fallback {
            self.pending_fallback = false;
            return;
        }
        let gone = self
            .worker
            .as_ref()
            .is_some_and(|w| w.values.send(Some(v)).is_err());
        if gone {
            // The worker is gone; the next ask restarts.
            self.worker = None;
        }
    }

    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

impl Drop for Sequential {
    fn drop(&mut self) {
        if let Some(w) = self.worker.take() {
            drop(w);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{minimize, testfns};
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::time::Duration;

    /// Coordinate search: tries ±step on each coordinate, halves the step on failure.
    fn coord_search(start: &[f64], scale: &[f64]) -> SeqAlgorithm {
        let (x0, s0) = (start.to_vec(), scale.to_vec());
        Box::new(move |f: &mut Evaluator<'_>| {
            let mut x = x0;
            let mut s = s0;
            let Some(mut fx) = f(&x) else { return };
            for _ in 0..30 {
                let mut improved = false;
                for j in 0..x.len() {
                    for sign in [1.0, -1.0] {
                        let mut y = x.clone();
                        y[j] += sign * s[j];
                        let Some(fy) = f(&y) else { return };
                        if fy < fx {
                            x = y;
                            fx = fy;
                            improved = true;
                        }
                    }
                }
                if !improved {
                    s.iter_mut().for_each(|v| *v *= 0.5);
                }
            }
        })
    }

    fn within(secs: u64, job: impl FnOnce() + Send + 'static) -> bool {
        let (tx, rx) = mpsc::channel();
        thread::spawn(move || {
            job();
            let _ = tx.send(());
        });
        rx.recv_timeout(Duration::from_secs(secs)).is_ok()
    }

    #[test]
    fn runs_restarts_and_uses_whole_budget() {
        let p = testfns::problem(3);
        let mut s = Sequential::new("coord", &p, Box::new(|x, sc, _| coord_search(x, sc)), 0);
        let out = minimize(&mut s, &testfns::sphere, 2000, false).unwrap();
        assert_eq!(out.evaluations, 2000);
        assert!(
            s.runs() > 1,
            "the 30-iteration search must have been restarted"
        );
        assert!(out.best_value < 1e-6, "{}", out.best_value);
    }

    #[test]
    fn drop_does_not_hang_while_the_worker_waits() {
        assert!(within(10, || {
            let p = testfns::problem(3);
            let mut s = Sequential::new("coord", &p, Box::new(|x, sc, _| coord_search(x, sc)), 0);
            let xs = s.ask(1); // worker now blocks waiting for the value
            assert_eq!(xs.len(), 1);
            drop(s);
        }));
        assert!(within(10, || {
            let p = testfns::problem(3);
            let mut s = Sequential::new("coord", &p, Box::new(|x, sc, _| coord_search(x, sc)), 0);
            let xs = s.ask(1);
            s.tell(&xs, &[1.0]); // worker is computing / sending its next point
            drop(s);
        }));
        assert!(within(10, || {
            let p = testfns::problem(3);
            let s = Sequential::new("coord", &p, Box::new(|x, sc, _| coord_search(x, sc)), 0);
            drop(s); // never started
        }));
    }

    #[test]
    fn aborted_algorithm_returns_and_thread_ends() {
        let finished = Arc::new(AtomicUsize::new(0));
        let fin = finished.clone();
        let p = testfns::problem(2);
        let factory: SeqFactory = Box::new(move |x, _, _| {
            let fin = fin.clone();
            let x = x.to_vec();
            Box::new(move |f: &mut Evaluator<'_>| {
                // Keeps asking until aborted.
                while f(&x).is_some() {}
                fin.fetch_add(1, Ordering::SeqCst);
            })
        });
        let mut s = Sequential::new("loop", &p, factory, 0);
        minimize(&mut s, &testfns::sphere, 10, false).unwrap();
        drop(s);
        assert_eq!(finished.load(Ordering::SeqCst), 1);
    }

    #[test]
    fn algorithm_that_asks_nothing_falls_back() {
        let p = testfns::problem(2);
        let factory: SeqFactory = Box::new(|_, _, _| Box::new(|_f: &mut Evaluator<'_>| {}));
        let mut s = Sequential::new("empty", &p, factory, 0);
        let out = minimize(&mut s, &testfns::sphere, 50, false).unwrap();
        assert_eq!(out.evaluations, 50);
        assert_eq!(s.runs(), MAX_EMPTY_RUNS);
    }

    #[test]
    fn panicking_algorithm_is_survived() {
        let p = testfns::problem(2);
        let factory: SeqFactory = Box::new(|x, _, _| {
            let x = x.to_vec();
            Box::new(move |f: &mut Evaluator<'_>| {
                let _ = f(&x);
                panic!("deliberate test panic");
            })
        });
        let mut s = Sequential::new("panics", &p, factory, 0);
        let out = minimize(&mut s, &testfns::sphere, 5, false).unwrap();
        assert_eq!(out.evaluations, 5);
    }
}
