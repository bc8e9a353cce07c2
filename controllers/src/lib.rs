//! Base-tracking and whole-body controllers of amstack (a pure crate: no I/O, no clock).
//!
//! This crate will own, once its issue lands:
//! - geometric PID in two forms: 6-DoF for the fully actuated vehicles and the EE-only oracle
//!   (position PID in the world frame, SO(3) attitude error e_R = ½(R_dᵀR − RᵀR_d)^∨), and the
//!   nested 4-DoF law (thrust direction + heading) for UA-Quad and UA-Hexa;
//! - L1 adaptive control on the PID baseline (state predictor, piecewise-constant adaptation,
//!   projection, low-pass filter);
//! - whole-body inverse kinematics (Levenberg–Marquardt over base pose and arm joints);
//! - the whole-body NMPC of the FA-Hexa (SQP-RTI).
//!
//! Every controller takes `dt` in seconds as an argument and the vehicle description from
//! `platform`; saturation feedback arrives from `allocation`.
