//! Measurements that run the solver rather than read a campaign: the paired design in this
//! process ([`paired`]), DD's predicted work imbalance over a run ([`imbalance`]), and the
//! gate's own error rates ([`calibrate`], which runs the gate's campaigns).

pub mod calibrate;
pub mod calibrate_ab;
pub mod imbalance;
pub mod paired;
