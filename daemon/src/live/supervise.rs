//! Supervision: every task and the sensing thread report their end (a
//! return, or a panic while unwinding) on one channel; before shutdown any
//! such end is fatal for the session.

/// Where ends are reported: what ended, and why when it was an error.
pub(crate) type Ended = tokio::sync::mpsc::UnboundedSender<(&'static str, Option<String>)>;

/// Spawn a task whose end (return or panic) is reported on `ended`.
pub(crate) fn supervise(
    what: &'static str,
    ended: &Ended,
    fut: impl std::future::Future<Output = Option<String>> + Send + 'static,
) -> tokio::task::JoinHandle<()> {
    let guard = EndGuard::new(what, ended.clone());
    tokio::spawn(async move {
        let why = fut.await;
        guard.done(why);
    })
}

/// Reports the end of a task or thread, panics included (the report is
/// sent from `Drop`, which runs while unwinding).
pub(crate) struct EndGuard {
    what: &'static str,
    ended: Ended,
    why: Option<Option<String>>,
}

impl EndGuard {
    pub(crate) fn new(what: &'static str, ended: Ended) -> EndGuard {
        EndGuard {
            what,
            ended,
            why: None,
        }
    }
    /// Ended normally, with a reason if it was an error.
    pub(crate) fn done(mut self, why: Option<String>) {
        self.why = Some(why);
    }
}

impl Drop for EndGuard {
    fn drop(&mut self) {
        let why = match self.why.take() {
            Some(why) => why,
            None if std::thread::panicking() => Some("it panicked".into()),
            None => Some("it was cancelled".into()),
        };
        let _ = self.ended.send((self.what, why));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A task or the sensing thread that panics or returns before shutdown
    /// is reported, so the session ends with an error instead of going on
    /// deaf.
    #[test]
    fn a_task_or_thread_that_panics_or_ends_is_reported() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async {
            let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
            let _task = supervise("receiver task", &tx, async {
                if std::hint::black_box(true) {
                    panic!("peer sent something odd");
                }
                None
            });
            let (what, why) = rx.recv().await.unwrap();
            assert_eq!(
                (what, why.as_deref()),
                ("receiver task", Some("it panicked"))
            );
            let _task = supervise("roller events task", &tx, async {
                Some("the roller driver stopped".to_string())
            });
            let (what, why) = rx.recv().await.unwrap();
            assert_eq!(
                (what, why.as_deref()),
                ("roller events task", Some("the roller driver stopped"))
            );
            let ended = tx.clone();
            let t = std::thread::spawn(move || {
                let _guard = EndGuard::new("sensing thread", ended);
                panic!("encoder blew up");
            });
            assert!(t.join().is_err());
            let (what, why) = rx.recv().await.unwrap();
            assert_eq!(
                (what, why.as_deref()),
                ("sensing thread", Some("it panicked"))
            );
            let ended = tx.clone();
            std::thread::spawn(move || EndGuard::new("sensing thread", ended).done(None))
                .join()
                .unwrap();
            assert_eq!(rx.recv().await.unwrap(), ("sensing thread", None));
        });
    }
}
