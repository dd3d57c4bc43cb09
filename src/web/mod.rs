//! The live page (`outputs.web`): the node serves one HTML page and a WebSocket. The page lists
//! the persons and shows each one's avatar rendered in the browser by Spark (three.js Gaussian
//! splatting, vendored under `web/vendor/`), skinned on the GPU by the live pose stream, with
//! orbit controls and the person's status (revision, views, pose age).
//!
//! What goes over the WebSocket ([`protocol`]): one binary frame per avatar revision (the
//! compact avatar's blobs, [`crate::compact::CompactAvatar`], behind a JSON header with the
//! skeleton) and JSON text frames for poses and statuses. A new page gets the latest of each
//! at once ([`LiveState`]); the node never waits for a page.
//!
//! Access ([`access`]): loopback by default; any other interface needs a token given on the
//! command line (a person's avatar is personal data), and WebSocket upgrades from another
//! origin are refused.
//!
//! Why not the Foxglove SDK's WebSocket server: it speaks Foxglove's protocol to Foxglove's
//! app (channels of schema-described messages), and the page would have to speak it too to get
//! binary avatars and poses; it has no token of its own on other interfaces; and it would bring
//! a second server for the page beside it. The ROS 2 topics already reach Foxglove through its
//! ROS 2 bridge (`launch_configs/foxglove_layout.json`). One small axum server does both here.

pub mod access;
mod assets;
pub mod protocol;
mod server;
mod state;

pub use server::{WebError, WebServer};
pub use state::{LiveState, Payload};
