//! The cold start: the library (`host/locate`, re-exported here) and the `locate` command's
//! run over one image or a video's frame ([`run`]), which writes its result folder.

pub use ::locate::*;

pub mod run;
