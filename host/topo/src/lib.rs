//! Topological mapping from polarization images (spec A3, A5): a scene renderer for the
//! simulator ([`scene`]), the map of places with their image samples and association in the
//! LMNN metric ([`map`]), the AUKF-SLAM filter state augmented with the node positions
//! ([`slam`]), a simulated survey with revisits and its evaluation ([`survey`]), and map export
//! (JSON, GraphML, a PNG plot of the graph over the trajectory: [`export`]); and the online mapper
//! fed by the firmware's own navigation solution, whose loop-closure fixes are the equivalent
//! independent measurements the firmware can fuse ([`live`]; it carries no truth: a simulation
//! scores its events against the truth with [`live_eval`], outside it).
//!
//! The online mapper of the closed loop ([`live`]) is fed by the firmware's own navigation
//! solution and sends its fixes to the head (`subnav_sil::map_loop`); the offline survey
//! ([`survey`], [`slam`]) runs the seed's AUKF-SLAM on its own dead reckoning.

pub mod export;
pub mod live;
pub mod live_eval;
pub mod lmnn;
pub mod map;
pub mod polar_image;
pub mod scene;
pub mod slam;
pub mod survey;
