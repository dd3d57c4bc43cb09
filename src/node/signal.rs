//! Stopping on a signal: the one future that `lhmpp run` and `lhmpp record` wait on.

/// Resolves on SIGINT or SIGTERM (SIGINT only off Unix). Must be polled inside a tokio runtime
/// with signal handling enabled.
pub async fn interrupt_or_terminate() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(e) => {
                tracing::warn!("cannot listen for SIGTERM: {e}");
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}
