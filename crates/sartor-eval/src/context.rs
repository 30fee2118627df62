//! The error plumbing sartor's tool crates share (this one and `sartor-pipeline`): a
//! [`Context`](crate::Context) trait that wraps any error with what was being done, and
//! [`ensure!`](crate::ensure) / [`bail!`](crate::bail) for plain faults.
//!
//! Each crate keeps its own error enum (one per crate, as the house style asks); these macros
//! write the same few impls for any enum with `Io { path, source }`, `Invalid(String)` and
//! `Context { context, source: Box<Self> }` variants, so the code exists once.

/// Give the calling crate's `Error` (with `Io`, `Invalid(String)` and `Context` variants) an
/// `Error::io` constructor and a `Context` trait implemented for `Result` and `Option`.
#[macro_export]
macro_rules! context_error {
    () => {
        impl Error {
            /// An I/O error on `path`.
            pub fn io(path: impl Into<std::path::PathBuf>, source: std::io::Error) -> Self {
                Self::Io {
                    path: path.into(),
                    source,
                }
            }
        }

        /// Adds what was being done to an error, as [`Error::Context`] (a missing value becomes
        /// [`Error::Invalid`] with the context as its message).
        pub trait Context<T> {
            /// Wrap the error with `context`.
            fn context(self, context: impl std::fmt::Display) -> Result<T>;
            /// Wrap the error with a context computed only on failure.
            fn with_context<C: std::fmt::Display>(self, context: impl FnOnce() -> C) -> Result<T>;
        }

        impl<T, E: Into<Error>> Context<T> for std::result::Result<T, E> {
            fn context(self, context: impl std::fmt::Display) -> Result<T> {
                self.map_err(|e| Error::Context {
                    context: context.to_string(),
                    source: Box::new(e.into()),
                })
            }
            fn with_context<C: std::fmt::Display>(self, context: impl FnOnce() -> C) -> Result<T> {
                self.map_err(|e| Error::Context {
                    context: context().to_string(),
                    source: Box::new(e.into()),
                })
            }
        }

        impl<T> Context<T> for Option<T> {
            fn context(self, context: impl std::fmt::Display) -> Result<T> {
                self.ok_or_else(|| Error::Invalid(context.to_string()))
            }
            fn with_context<C: std::fmt::Display>(self, context: impl FnOnce() -> C) -> Result<T> {
                self.ok_or_else(|| Error::Invalid(context().to_string()))
            }
        }
    };
}

/// Return the calling crate's `Error::Invalid` with a formatted message unless `cond` holds.
// `crate` (not `$crate`) on purpose: the error is the caller's.
#[allow(clippy::crate_in_macro_def)]
#[macro_export]
macro_rules! ensure {
    ($cond:expr, $($arg:tt)+) => {
        if !$cond {
            return Err(crate::Error::Invalid(format!($($arg)+)));
        }
    };
}

/// Return the calling crate's `Error::Invalid` with a formatted message.
#[allow(clippy::crate_in_macro_def)]
#[macro_export]
macro_rules! bail {
    ($($arg:tt)+) => {
        return Err(crate::Error::Invalid(format!($($arg)+)))
    };
}
