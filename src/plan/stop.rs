//! How the planners' searches stop. By default a search ends on a budget of
//! work (kicks, iterations, generations) that scales with the instance, so
//! the same job, config and seed give the same plan whatever the load and
//! the number of cores. A wall-clock cap the user sets (`--time-limit`, the
//! config's `time_limit`) may end a search first; the plan may then differ
//! from run to run, and the report says so.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// What ended a planning step's searches (`search_stopped_by` in the reports).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum SearchStop {
    /// Every search ran its work budget (or the planner does not search):
    /// the plan is the same on any machine.
    #[default]
    Budget,
    /// The user's time limit ended a search before its budget.
    TimeLimit,
}

impl SearchStop {
    pub fn as_str(self) -> &'static str {
        match self {
            SearchStop::Budget => "budget",
            SearchStop::TimeLimit => "time-limit",
        }
    }

    /// The stop of a plan joined from two planning steps.
    pub fn and(self, other: SearchStop) -> SearchStop {
        if self == SearchStop::TimeLimit || other == SearchStop::TimeLimit {
            SearchStop::TimeLimit
        } else {
            SearchStop::Budget
        }
    }
}

/// A wall-clock cap on a planning step's searches (none: only their budgets
/// end them), and whether it ended one. The threads of a step share it.
#[derive(Debug, Default)]
pub struct TimeCap {
    deadline: Option<Instant>,
    reached: AtomicBool,
}

impl TimeCap {
    /// No cap.
    pub fn none() -> TimeCap {
        TimeCap::default()
    }

    /// A cap `limit` from now (none: no cap).
    pub fn after(limit: Option<Duration>) -> TimeCap {
        TimeCap { deadline: limit.map(|l| Instant::now() + l), reached: AtomicBool::new(false) }
    }

    /// Whether the cap has passed. A search asks before more work and stops
    /// when it has; the cap then remembers that it ended a search.
    pub fn reached(&self) -> bool {
        match self.deadline {
            Some(d) if Instant::now() >= d => {
                self.reached.store(true, Ordering::Relaxed);
                true
            }
            _ => false,
        }
    }

    /// Time left before the cap (none: no cap).
    pub fn remaining(&self) -> Option<Duration> {
        self.deadline.map(|d| d.saturating_duration_since(Instant::now()))
    }

    /// What ended the searches that asked this cap.
    pub fn stop(&self) -> SearchStop {
        if self.reached.load(Ordering::Relaxed) {
            SearchStop::TimeLimit
        } else {
            SearchStop::Budget
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cap_tells_whether_it_ended_a_search() {
        let none = TimeCap::none();
        assert!(!none.reached());
        assert_eq!(none.stop(), SearchStop::Budget);
        let far = TimeCap::after(Some(Duration::from_secs(3600)));
        assert!(!far.reached());
        assert_eq!(far.stop(), SearchStop::Budget);
        let past = TimeCap::after(Some(Duration::ZERO));
        assert_eq!(past.stop(), SearchStop::Budget, "a cap no search asked ended nothing");
        assert!(past.reached());
        assert_eq!(past.stop(), SearchStop::TimeLimit);
        assert_eq!(SearchStop::Budget.and(SearchStop::TimeLimit), SearchStop::TimeLimit);
        assert_eq!(SearchStop::Budget.and(SearchStop::Budget), SearchStop::Budget);
        assert_eq!(serde_json::to_string(&SearchStop::TimeLimit).unwrap(), "\"time-limit\"");
    }
}
