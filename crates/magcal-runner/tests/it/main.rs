//! The integration tests of `magcal`, linked into one binary: the real binary end to end on
//! temporary directories (every run through [`common::magcal`] and its memory limit), and the
//! fuzzers of the scenario parser and the log commands.

mod browser;
mod common;

mod apply_next;
mod attitudes;
mod bad_input;
mod bad_logs;
mod budget;
mod calibrate;
mod calibrate_one_field;
mod cli;
mod dataflash;
mod evaluate;
mod exit_codes;
mod export;
mod fit_bound;
mod fuzz;
mod gps;
mod hostile;
mod live;
mod live_guide;
mod live_quad;
mod live_send;
mod live_sitl;
mod log_outputs;
mod loop_design_log;
mod motor;
mod reference;
mod replay;
mod report;
mod report_evaluate;
mod report_next;
mod report_replay;
mod report_run;
mod result_set;
mod tlog;
mod ulog;
mod vector;
mod verdict;
