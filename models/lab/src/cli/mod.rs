//! The command line of `telextiles-lab`: every subcommand's arguments.

pub(crate) mod args;
