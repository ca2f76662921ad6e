//! The log as the appliance writes it: plain text on stderr (colour only for a terminal), and
//! lines that repeat rate-limited so no client can fill a disk or the journal.
//!
//! Repetition is judged per place in the code (`tracing-throttle` keys on the callsite, its
//! level and the remaining fields), ignoring who caused it (`peer`, `file`) and the message text:
//! a thousand refused writes from a thousand connections are one line repeated, not a thousand
//! different ones. Each place may burst [`BURST`] lines, then [`PER_MINUTE`] a minute; what was
//! held back is counted and said in a summary line every `summary_every`. The camera workers'
//! lines are exempt: one per result, they are the record of what the PLC was told and come no
//! faster than the frames.

use std::time::Duration;

use tracing_subscriber::filter::FilterExt;
use tracing_subscriber::fmt::MakeWriter;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::{EnvFilter, Layer};
use tracing_throttle::{Policy, TracingRateLimitLayer};

/// An error and every cause behind it, "outer: inner: root", as the log and the page write it
/// (a bare `to_string` drops the cause that names the file).
pub fn error_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        text.push_str(": ");
        text.push_str(&c.to_string());
        cause = c.source();
    }
    text
}

/// Lines one place in the code may write at once before it is rate-limited.
pub const BURST: f64 = 20.0;
/// Lines a minute one place may write after its burst.
pub const PER_MINUTE: f64 = 12.0;
/// Target of the per-result lines, never rate-limited.
const RESULTS_TARGET: &str = "lfi_bridge::appliance::camera";
/// Fields that name who or what caused a line, not which line it is.
const CAUSE_FIELDS: [&str; 7] = ["message", "peer", "file", "frame", "acq_id", "part", "of"];

/// How repeated lines are limited; `None` writes every line (the one-shot commands).
#[derive(Debug, Clone, Copy)]
pub struct Throttle {
    /// How often the count of held-back lines is written.
    pub summary_every: Duration,
}

impl Default for Throttle {
    fn default() -> Self {
        Self { summary_every: Duration::from_secs(60) }
    }
}

/// The appliance's subscriber writing to `writer`. `level` is the default filter (the
/// `RUST_LOG` environment variable overrides it). With a throttle this must be called inside a
/// tokio runtime: the summaries are written by a task.
pub fn subscriber<W>(level: &str, ansi: bool, writer: W, throttle: Option<Throttle>) -> Box<dyn tracing::Subscriber + Send + Sync>
where
    W: for<'w> MakeWriter<'w> + Send + Sync + 'static,
{
    let env = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(level));
    let fmt = tracing_subscriber::fmt::layer().with_writer(writer).with_ansi(ansi);
    let registry = tracing_subscriber::registry();
    match throttle.and_then(rate_limit) {
        Some(limit) => Box::new(registry.with(fmt.with_filter(env.and(limit)))),
        None => Box::new(registry.with(fmt.with_filter(env))),
    }
}

fn rate_limit(t: Throttle) -> Option<TracingRateLimitLayer> {
    let policy = Policy::token_bucket(BURST, PER_MINUTE / 60.0).ok()?;
    let built = TracingRateLimitLayer::builder()
        .with_policy(policy)
        .with_excluded_fields(CAUSE_FIELDS.iter().map(|f| f.to_string()).collect())
        .with_exempt_targets(vec![RESULTS_TARGET.to_string()])
        .with_active_emission(true)
        .with_summary_interval(t.summary_every)
        .build();
    match built {
        Ok(layer) => Some(layer),
        Err(e) => {
            // Only reachable with a zero interval; the log then stays unlimited, and says so.
            eprintln!("log rate limit not set up ({e}); every line will be written");
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_error_chain_names_every_cause() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = crate::kb::KbError::Read { path: "/srv/kb.toml".into(), source: io };
        assert_eq!(error_chain(&e), "cannot read knowledge base /srv/kb.toml: no such file");
    }
}
