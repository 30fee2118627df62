//! Progress bars (indicatif) for the library's progress traits, and the Ctrl-C stop flag.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use indicatif::{ProgressBar, ProgressStyle};
use sartor_model::EpochRecord;

/// One bar per phase of a long job (`sartor_eval::Progress`).
pub struct Bar {
    bar: ProgressBar,
}

impl Bar {
    /// A bar, drawn on stderr when it is a terminal.
    pub fn new() -> Self {
        Self {
            bar: ProgressBar::new(0),
        }
    }
}

impl Default for Bar {
    fn default() -> Self {
        Self::new()
    }
}

impl sartor_eval::Progress for Bar {
    fn start(&self, phase: &str, total: u64, unit: &str) {
        self.bar.reset();
        self.bar.set_length(total);
        self.bar.set_position(0);
        if let Ok(style) = ProgressStyle::with_template(&format!(
            "{{spinner}} {phase} [{{elapsed_precise}}] {{wide_bar}} {{pos}}/{{len}} {unit} \
             ({{per_sec}}, ETA {{eta}}) {{msg}}"
        )) {
            self.bar.set_style(style);
        }
    }
    fn inc(&self, n: u64) {
        self.bar.inc(n);
    }
    fn message(&self, text: &str) {
        self.bar.set_message(text.to_owned());
    }
    fn println(&self, line: &str) {
        self.bar.println(line);
    }
    fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

/// Training progress (`sartor_model::Progress`): steps of the epoch, loss and validation error.
pub struct TrainBar {
    bar: ProgressBar,
    model: String,
    epochs: usize,
    last_val: Option<f64>,
}

impl TrainBar {
    /// A bar for the models trained one after the other.
    pub fn new() -> Self {
        let bar = ProgressBar::new(1);
        if let Ok(style) = ProgressStyle::with_template(
            "{prefix:>14} {bar:30} {pos}/{len} {msg} [{elapsed_precise}, eta {eta}]",
        ) {
            bar.set_style(style);
        }
        Self {
            bar,
            model: String::new(),
            epochs: 0,
            last_val: None,
        }
    }

    /// Clear the bar.
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

impl Default for TrainBar {
    fn default() -> Self {
        Self::new()
    }
}

impl sartor_model::Progress for TrainBar {
    fn start(
        &mut self,
        model: &str,
        epoch: usize,
        epochs: usize,
        steps_per_epoch: usize,
        steps_done: usize,
    ) {
        if self.model != model {
            self.last_val = None;
        }
        self.model = model.into();
        self.epochs = epochs;
        self.bar.set_length(steps_per_epoch as u64);
        self.bar.set_position(steps_done as u64);
        self.bar.set_prefix(format!("{model} {epoch}/{epochs}"));
    }
    fn step(&mut self, loss: f64) {
        self.bar.inc(1);
        let val = self
            .last_val
            .map_or_else(|| "—".into(), |v| format!("{v:.2} mm"));
        self.bar.set_message(format!("loss {loss:.4}, val {val}"));
    }
    fn epoch(&mut self, record: &EpochRecord) {
        self.last_val = record.val_error_mm;
        if record.epoch == self.epochs || self.bar.is_hidden() && record.epoch.is_multiple_of(10) {
            self.bar.println(format!(
                "{} epoch {}/{}: loss {:.5}, validation {}",
                self.model,
                record.epoch,
                self.epochs,
                record.train_loss,
                record
                    .val_error_mm
                    .map_or_else(|| "—".into(), |v| format!("{v:.3} mm")),
            ));
        }
    }
}

/// A flag set by Ctrl-C: training checkpoints after the current batch and returns. A second
/// Ctrl-C ends the process.
pub fn stop_flag() -> Arc<AtomicBool> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    // A handler may already be installed (a command that trains twice in one process); then
    // Ctrl-C ends the process and the last epoch's checkpoint is what a resume starts from.
    let _ = ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        eprintln!("\nstopping after this batch (Ctrl-C again to quit at once)");
    });
    stop
}
