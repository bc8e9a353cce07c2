//! Whole-body inverse kinematics (being written).
