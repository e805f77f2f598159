//! The machine benchmark (`tools/machine-bench`): the release firmware's machine code on the
//! chip model of `tools/stm32emu` (the emulated board's), instrumented instruction by
//! instruction, for the CPU cost of the wheel's edge interrupt and of the SDO path, and for
//! the worst-case stack depth.
//!
//! The Python side runs in the chip model's venv (`target/emu-venv`, from
//! `tools/stm32emu/requirements.txt`), first its unit tests (pytest), then the
//! benchmark. The benchmark prints the CPU figures itself and writes the stack figures and
//! the wheel edge's figures (its worst cycles, the longest its interrupt is held off, its
//! worst latency to the port read, the highest merge-free edge rate with the CAN side at
//! its busiest) to a small tab-separated file that this module parses, prints and checks
//! against the budgets.

use std::fmt::Write as _;
use std::path::Path;

use xshell::cmd;

use crate::{pyenv, shell};

/// The benchmark's folder (its unit tests, run by pytest, are `test_*.py` there).
const DIR: &str = "tools/machine-bench";
/// The benchmark script.
const SCRIPT: &str = "tools/machine-bench/bench.py";

/// One preemption level: its NVIC priority byte, its deepest handler and that handler's
/// stack use (bytes below the exception frame).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Level {
    /// Hardware priority byte (0 = most urgent; SysTick keeps 0).
    pub priority: u8,
    /// The handler that went deepest.
    pub handler: String,
    /// Its stack use in bytes, without the exception frame.
    pub depth: u32,
    /// Every handler at this priority.
    pub handlers: Vec<String>,
}

/// Worst cycles of one wheel edge, exception entry and exit included, at zero wait states.
pub const EDGE_CYCLES_LIMIT: u32 = 120;
/// The lowest acceptable edge rate with no merged edge while the CAN side is at its busiest:
/// a 600-PPR encoder (2 400 edges per turn) at 10 turns per second.
pub const MERGE_FREE_RATE_LIMIT_HZ: u32 = 24_000;

/// The stack and edge figures the benchmark measured.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MachineReport {
    /// Worst cycles of one wheel edge (EXTI9_5), entry and exit included.
    pub edge_cycles: u32,
    /// Worst cycles from a wheel edge to its port read, over every scenario.
    pub edge_latency: u32,
    /// The longest stretch the wheel's interrupt was held off, cycles (masking or a handler
    /// at its priority).
    pub edge_held: u32,
    /// The highest edge rate with no merged edge while the CAN side is at its busiest, Hz.
    pub merge_free_hz: u32,
    /// Deepest thread-mode use (init, idle).
    pub thread: u32,
    /// Each preemption level, most urgent first.
    pub levels: Vec<Level>,
    /// Bytes the hardware stacks per exception, alignment included.
    pub frame: u32,
    /// Thread mode plus every level's deepest handler and frame.
    pub total: u32,
    /// The lowest SP seen in the run, as bytes below the top of the stack.
    pub lowest: u32,
    /// The deepest word of the painted stack that was overwritten, same measure.
    pub painted: u32,
    /// Room between the end of static RAM and the top of RAM.
    pub region: u32,
}

fn number(field: Option<&str>, line: &str) -> Result<u32, String> {
    field
        .and_then(|f| f.trim().parse().ok())
        .ok_or_else(|| format!("bad number in stack report line `{line}`"))
}

impl MachineReport {
    /// Parses the benchmark's report: `key<TAB>value` lines, `level` lines with priority,
    /// deepest handler, depth and the comma-separated handlers of the level.
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut report = MachineReport {
            edge_cycles: 0,
            edge_latency: 0,
            edge_held: 0,
            merge_free_hz: 0,
            thread: 0,
            levels: Vec::new(),
            frame: 0,
            total: 0,
            lowest: 0,
            painted: 0,
            region: 0,
        };
        let mut seen = Vec::new();
        for line in text.lines().filter(|l| !l.trim().is_empty()) {
            let mut fields = line.split('\t');
            let key = fields.next().unwrap_or_default();
            if key == "level" {
                let priority = number(fields.next(), line)?;
                let priority = u8::try_from(priority)
                    .map_err(|_| format!("priority out of range in `{line}`"))?;
                let handler = fields
                    .next()
                    .filter(|h| !h.is_empty())
                    .ok_or_else(|| format!("no handler in `{line}`"))?
                    .to_string();
                let depth = number(fields.next(), line)?;
                let handlers = fields
                    .next()
                    .unwrap_or_default()
                    .split(',')
                    .filter(|h| !h.is_empty())
                    .map(str::to_string)
                    .collect();
                report.levels.push(Level {
                    priority,
                    handler,
                    depth,
                    handlers,
                });
                continue;
            }
            let value = number(fields.next(), line)?;
            let slot = match key {
                "thread" => &mut report.thread,
                "frame" => &mut report.frame,
                "total" => &mut report.total,
                "lowest" => &mut report.lowest,
                "painted" => &mut report.painted,
                "region" => &mut report.region,
                "edge" => &mut report.edge_cycles,
                "latency" => &mut report.edge_latency,
                "held" => &mut report.edge_held,
                "rate" => &mut report.merge_free_hz,
                other => return Err(format!("unknown key `{other}` in the stack report")),
            };
            *slot = value;
            seen.push(key.to_string());
        }
        for key in [
            "thread", "frame", "total", "region", "edge", "latency", "held", "rate",
        ] {
            if !seen.iter().any(|k| k == key) {
                return Err(format!("the machine report has no `{key}` line"));
            }
        }
        if report.levels.is_empty() {
            return Err("the stack report lists no preemption level".into());
        }
        let sum = report.thread
            + report
                .levels
                .iter()
                .map(|l| l.depth + report.frame)
                .sum::<u32>();
        if sum != report.total {
            return Err(format!(
                "the stack report's total {} is not the sum of its parts {sum}",
                report.total
            ));
        }
        Ok(report)
    }

    /// The table `cargo xtask` prints, with the headroom against `budget`.
    pub fn render(&self, budget: u32) -> String {
        let mut out = String::from(
            "xtask: worst-case stack of the release firmware (machine benchmark; each \
             preemption level's deepest handler stacked on thread mode)\n",
        );
        let _ = writeln!(
            out,
            "  thread mode (init, idle)          {:>6} B",
            self.thread
        );
        for level in &self.levels {
            // RTIC's logical priority for 4 NVIC priority bits (byte 0, the reset priority,
            // is logical 16).
            let name = format!("priority {}", 16 - u32::from(level.priority >> 4));
            let _ = writeln!(
                out,
                "  {name:<14} {:<18} {:>6} B + {} B frame   ({})",
                level.handler,
                level.depth,
                self.frame,
                level.handlers.join(", ")
            );
        }
        let _ = writeln!(
            out,
            "  total {:>6} B of the {budget} B stack budget, headroom {} B (room below static \
             RAM: {} B)",
            self.total,
            i64::from(budget) - i64::from(self.total),
            self.region
        );
        let _ = writeln!(
            out,
            "  this run's deepest point: SP {} B below the top, painted stack overwritten to {} B",
            self.lowest, self.painted
        );
        out
    }

    /// The wheel edge's figures against their limits, for the console.
    pub fn render_edge(&self) -> String {
        format!(
            "xtask: wheel edge: worst {} cycles (limit {EDGE_CYCLES_LIMIT}); its interrupt held \
             off {} cycles at most; worst latency to its port read {} cycles = {:.2} us at \
             72 MHz; highest edge rate with no merged edge, CAN side busiest: {:.1} kHz (limit \
             {:.1} kHz)\n",
            self.edge_cycles,
            self.edge_held,
            self.edge_latency,
            f64::from(self.edge_latency) / 72.0,
            f64::from(self.merge_free_hz) / 1000.0,
            f64::from(MERGE_FREE_RATE_LIMIT_HZ) / 1000.0
        )
    }

    /// Errors when a wheel edge costs more than [`EDGE_CYCLES_LIMIT`] or the merge-free edge
    /// rate with the CAN side at its busiest is below [`MERGE_FREE_RATE_LIMIT_HZ`].
    pub fn check_edge(&self) -> Result<(), String> {
        if self.edge_cycles > EDGE_CYCLES_LIMIT {
            return Err(format!(
                "a wheel edge costs {} cycles, over the {EDGE_CYCLES_LIMIT}-cycle limit",
                self.edge_cycles
            ));
        }
        if self.merge_free_hz < MERGE_FREE_RATE_LIMIT_HZ {
            return Err(format!(
                "edges merge above {} Hz with the CAN side at its busiest, below the \
                 {MERGE_FREE_RATE_LIMIT_HZ} Hz limit",
                self.merge_free_hz
            ));
        }
        Ok(())
    }

    /// Errors when the worst case is over `budget` or the stack region, or when the painted
    /// stack contradicts the SP measurement (a write below the lowest SP seen).
    pub fn check(&self, budget: u32) -> Result<(), String> {
        if self.total > budget {
            return Err(format!(
                "worst-case stack {} B is over the {budget} B budget",
                self.total
            ));
        }
        if self.total > self.region {
            return Err(format!(
                "worst-case stack {} B does not fit the {} B between static RAM and the top",
                self.total, self.region
            ));
        }
        if self.painted > self.lowest {
            return Err(format!(
                "the painted stack was written {} B deep, below the lowest SP seen ({} B): \
                 the SP tracking missed something",
                self.painted, self.lowest
            ));
        }
        Ok(())
    }
}

/// Runs the benchmark's unit tests and the benchmark on `elf`; returns the stack figures.
/// `quiet` prints a one-line CPU summary instead of the full report.
pub fn run(
    root: &Path,
    target_dir: &Path,
    elf: &Path,
    quiet: bool,
) -> Result<MachineReport, String> {
    let python = pyenv::emu_python(root, target_dir)?;
    // pytest, as every Python test here (tools/pytest.ini: no cache folder in the source
    // tree); the tests that boot the image take this one.
    let sh = &shell::at(root)?;
    shell::run(cmd!(sh, "{python} -m pytest -q {DIR}").env("HANDWHEEL_BOARD_ELF", elf))?;
    let out_dir = target_dir.join("machine-bench");
    std::fs::create_dir_all(&out_dir)
        .map_err(|e| format!("cannot create {}: {e}", out_dir.display()))?;
    let report_path = out_dir.join("stack.tsv");
    let _ = std::fs::remove_file(&report_path);
    let quiet = quiet.then_some("--quiet");
    shell::run(cmd!(
        sh,
        "{python} {SCRIPT} {elf} --stack-report {report_path} {quiet...}"
    ))?;
    let text = std::fs::read_to_string(&report_path)
        .map_err(|e| format!("cannot read {}: {e}", report_path.display()))?;
    MachineReport::parse(&text)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SAMPLE: &str = "thread\t1152\n\
        level\t0\tSysTick\t40\tSysTick\n\
        level\t192\tEXTI9_5\t24\tEXTI9_5\n\
        level\t208\tUSB_LP_CAN_RX0\t208\tCAN_SCE,USB_HP_CAN_TX,USB_LP_CAN_RX0\n\
        level\t224\tTIM3\t1464\tTIM3\n\
        level\t240\tTIM2\t80\tTIM2\n\
        frame\t36\n\
        total\t3148\n\
        lowest\t1504\n\
        painted\t1244\n\
        region\t18172\n\
        edge\t96\n\
        latency\t151\n\
        held\t127\n\
        rate\t476821\n";

    #[test]
    fn parses_the_benchmark_report() {
        let report = MachineReport::parse(SAMPLE).unwrap();
        assert_eq!(report.thread, 1152);
        assert_eq!(report.levels.len(), 5);
        assert_eq!(
            report.levels[2],
            Level {
                priority: 208,
                handler: "USB_LP_CAN_RX0".into(),
                depth: 208,
                handlers: vec![
                    "CAN_SCE".into(),
                    "USB_HP_CAN_TX".into(),
                    "USB_LP_CAN_RX0".into()
                ],
            }
        );
        assert_eq!(report.frame, 36);
        assert_eq!(report.total, 3148);
        assert_eq!(report.lowest, 1504);
        assert_eq!(report.painted, 1244);
        assert_eq!(report.region, 18172);
        assert_eq!((report.edge_cycles, report.edge_latency), (96, 151));
        assert_eq!((report.edge_held, report.merge_free_hz), (127, 476_821));
    }

    #[test]
    fn checks_the_edge_limits() {
        let report = MachineReport::parse(SAMPLE).unwrap();
        assert_eq!(report.check_edge(), Ok(()));
        let mut slow = report.clone();
        slow.edge_cycles = 120;
        assert_eq!(slow.check_edge(), Ok(()));
        slow.edge_cycles = 121;
        assert!(slow.check_edge().unwrap_err().contains("121 cycles"));
        let mut merging = report.clone();
        merging.merge_free_hz = 24_000;
        assert_eq!(merging.check_edge(), Ok(()));
        merging.merge_free_hz = 23_999;
        assert!(merging.check_edge().unwrap_err().contains("23999 Hz"));
        let no_rate = SAMPLE.replace("rate\t476821\n", "");
        assert!(MachineReport::parse(&no_rate).unwrap_err().contains("rate"));
        let no_latency = SAMPLE.replace("latency\t151\n", "");
        assert!(MachineReport::parse(&no_latency)
            .unwrap_err()
            .contains("latency"));
    }

    #[test]
    fn rejects_a_total_that_is_not_the_sum() {
        let text = SAMPLE.replace("total\t3148", "total\t3000");
        let error = MachineReport::parse(&text).unwrap_err();
        assert!(error.contains("3000"), "{error}");
        assert!(error.contains("3148"), "{error}");
    }

    #[test]
    fn rejects_missing_and_unknown_lines() {
        let no_region = SAMPLE.replace("region\t18172\n", "");
        assert!(MachineReport::parse(&no_region)
            .unwrap_err()
            .contains("region"));
        let unknown = format!("{SAMPLE}heap\t12\n");
        assert!(MachineReport::parse(&unknown).unwrap_err().contains("heap"));
        let no_levels: String = SAMPLE
            .lines()
            .filter(|l| !l.starts_with("level"))
            .map(|l| format!("{l}\n"))
            .collect::<String>()
            .replace("total\t3148", "total\t1152");
        assert!(MachineReport::parse(&no_levels)
            .unwrap_err()
            .contains("no preemption level"));
    }

    #[test]
    fn checks_the_budget_and_the_paint() {
        let report = MachineReport::parse(SAMPLE).unwrap();
        assert_eq!(report.check(4096), Ok(()));
        assert_eq!(report.check(3148), Ok(()));
        let over = report.check(3147).unwrap_err();
        assert!(over.contains("3148 B is over the 3147 B budget"), "{over}");
        let mut bad_paint = report.clone();
        bad_paint.painted = 1600;
        assert!(bad_paint.check(4096).unwrap_err().contains("painted"));
        let mut no_room = report;
        no_room.region = 3000;
        assert!(no_room.check(4096).unwrap_err().contains("3000"));
    }

    #[test]
    fn renders_levels_and_headroom() {
        let text = MachineReport::parse(SAMPLE).unwrap().render(4096);
        assert!(text.contains("priority 16"), "{text}");
        assert!(text.contains("priority 4"), "{text}");
        assert!(text.contains("priority 1"), "{text}");
        assert!(text.contains("headroom 948 B"), "{text}");
        assert!(
            text.contains("CAN_SCE, USB_HP_CAN_TX, USB_LP_CAN_RX0"),
            "{text}"
        );
    }
}
