//! What was recorded: the CSV row and its columns, the file, older schemas, the manifest and
//! the campaign folder's lock.

pub mod columns;
pub mod csv;
pub mod filled;
pub mod legacy;
pub mod lock;
pub mod manifest;
pub mod record;
