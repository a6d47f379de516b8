//! What was recorded: the CSV row and its columns, the file, older schemas, rows repeating a
//! run, the manifest (with a bundle's record of its build), the campaign folder's lock and
//! its disk failing (full, read-only).

pub mod bundle;
pub mod columns;
pub mod csv;
pub mod disk;
pub mod filled;
pub mod legacy;
pub mod lock;
pub mod manifest;
pub mod record;
pub mod repeats;
