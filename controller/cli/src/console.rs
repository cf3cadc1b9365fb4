//! The person at the terminal during calibration: each step explained and confirmed with Enter,
//! progress as a bar.

use std::io::{BufRead, Write as _};

use calibration::operator::{Aborted, Operator, Request};

/// The person at the terminal: each step is explained and confirmed with Enter (`q` aborts);
/// `yes` answers every question (allowed in the mirror only).
#[derive(Debug)]
pub struct ConsoleOperator {
    yes: bool,
    bar: Option<(String, indicatif::ProgressBar)>,
}

impl ConsoleOperator {
    /// A console operator; `yes` confirms everything without asking.
    pub fn new(yes: bool) -> Self {
        Self { yes, bar: None }
    }

    fn ask(&mut self, prompt: &str) -> Result<(), Aborted> {
        self.finish_bar();
        if self.yes {
            println!("{prompt} [--yes]");
            return Ok(());
        }
        print!("{prompt} [Enter: go on, q: abort] ");
        let _ = std::io::stdout().flush();
        let mut line = String::new();
        match std::io::stdin().lock().read_line(&mut line) {
            Ok(n) if n > 0 && !matches!(line.trim(), "q" | "Q" | "n" | "N" | "no" | "abort") => Ok(()),
            Ok(0) => {
                println!(
                    "\nstandard input ended: nobody is there to answer (run it at a terminal, or pipe the answers; \
                     on the mirror --yes answers for you)"
                );
                Err(Aborted)
            }
            _ => Err(Aborted),
        }
    }

    fn finish_bar(&mut self) {
        if let Some((_, bar)) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

impl Operator for ConsoleOperator {
    fn request(&mut self, request: Request<'_>) -> Result<(), Aborted> {
        match request {
            Request::Confirm { what } => self.ask(&format!("\n{what}.\nGo ahead?")),
            Request::ClampJig { label, joints, pose } => {
                let mut text = format!("Clamp the robot in jig setting {label}:");
                for (name, q) in joints.iter().zip(pose) {
                    text.push_str(&format!("\n  {name:<20} {:>8.2}°", q.to_degrees()));
                }
                self.ask(&format!("{text}\nEvery joint clamped?"))
            }
            Request::ReleaseJig => self.ask("Take the robot out of the jig; it hangs on its stand. Done?"),
            Request::Watch { joint, .. } => self.ask(&format!(
                "Watch {joint}: it will move slowly under low torque until it rests on its stops. Ready?"
            )),
            Request::HoldBase { label, rpy_deg } => self.ask(&format!(
                "Hold the robot's base still {label} (roll {:.0}°, pitch {:.0}°, yaw {:.0}°). Still?",
                rpy_deg[0], rpy_deg[1], rpy_deg[2]
            )),
        }
    }

    fn direction_seen(&mut self, _index: usize, joint: &str) -> Result<f64, Aborted> {
        self.finish_bar();
        if self.yes {
            // Nobody answers for the person here: only the mirror's hands can see.
            return Err(Aborted);
        }
        loop {
            print!("Did {joint} turn in its positive direction (the model's axis)? [+/-, q: abort] ");
            let _ = std::io::stdout().flush();
            let mut line = String::new();
            match std::io::stdin().lock().read_line(&mut line) {
                Ok(n) if n > 0 => match line.trim() {
                    "+" | "y" | "yes" => return Ok(1.0),
                    "-" | "n" | "no" => return Ok(-1.0),
                    "q" | "abort" => return Err(Aborted),
                    _ => continue,
                },
                _ => return Err(Aborted),
            }
        }
    }

    fn say(&mut self, line: &str) {
        self.finish_bar();
        println!("{line}");
    }

    fn progress(&mut self, step: &str, done: f64) {
        if self.bar.as_ref().is_none_or(|(s, _)| s != step) {
            self.finish_bar();
            let bar = indicatif::ProgressBar::new(100).with_message(step.to_owned());
            bar.set_style(
                indicatif::ProgressStyle::with_template("  {msg:<14} [{bar:30}] {percent:>3}%")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            self.bar = Some((step.to_owned(), bar));
        }
        if let Some((_, bar)) = &self.bar {
            bar.set_position((done * 100.0).round() as u64);
        }
    }
}
