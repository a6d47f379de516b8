//! The command line of `mpm-bench`: each command's clap arguments (`main.rs` holds the
//! command list), converted into the options its library function takes (the library has
//! no clap); `run` and `topology` are commands of the program itself.

pub mod ab;
pub mod analysis;
pub mod export;
pub mod measure;
pub mod parse;
pub mod run;
pub mod tables;
pub mod topology;
