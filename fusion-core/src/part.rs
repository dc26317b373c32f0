//! One part of a camera frame's measurements, of either kind (protocol/PROTOCOL.md §3, step 5):
//! 2D/3D correspondences (eq. 10) or, since protocol 3.2, contour correspondences (eq. 10c). The
//! device applies a part's items one at a time through [`Item::apply`], whatever their kind.

use core::slice;

use protocol::{ContourPoint, Contours, Correspondence, Correspondences};

use crate::kernels::Kernels;
use crate::models::contour::{self, ContourObservation};
use crate::models::correspondence::{self, Observation, Rejection};
use crate::params::Params;
use crate::state::{State, StateVec};

/// A part of one frame, as the host sent it.
#[derive(Clone, Copy, Debug)]
pub enum Part<'a> {
    /// 2D/3D correspondences.
    Points(&'a Correspondences),
    /// Contour correspondences.
    Contours(&'a Contours),
}

impl<'a> Part<'a> {
    /// The frame id of the core's prediction.
    pub fn frame_id(&self) -> u32 {
        match self {
            Part::Points(c) => c.frame_id,
            Part::Contours(c) => c.frame_id,
        }
    }

    /// The frame's trigger time [µs].
    pub fn trigger_us(&self) -> u64 {
        match self {
            Part::Points(c) => c.trigger_us,
            Part::Contours(c) => c.trigger_us,
        }
    }

    /// This part's index among the frame's parts of both kinds.
    pub fn index(&self) -> u8 {
        match self {
            Part::Points(c) => c.part,
            Part::Contours(c) => c.part,
        }
    }

    /// The frame's number of parts.
    pub fn parts(&self) -> u8 {
        match self {
            Part::Points(c) => c.parts,
            Part::Contours(c) => c.parts,
        }
    }

    /// Whether the part holds no measurement.
    pub fn is_empty(&self) -> bool {
        match self {
            Part::Points(c) => c.items.is_empty(),
            Part::Contours(c) => c.items.is_empty(),
        }
    }

    /// The part's measurements, in the order sent.
    pub fn items(&self) -> Items<'a> {
        match *self {
            Part::Points(c) => Items::Points(c.items.iter()),
            Part::Contours(c) => Items::Contours(c.items.iter()),
        }
    }
}

/// One measurement of a part.
#[derive(Clone, Copy, Debug)]
pub enum Item<'a> {
    /// A 2D/3D correspondence.
    Point(&'a Correspondence),
    /// A contour correspondence.
    Contour(&'a ContourPoint),
}

/// Iterator over a [`Part`]'s measurements.
#[derive(Clone, Debug)]
pub enum Items<'a> {
    /// Over 2D/3D correspondences.
    Points(slice::Iter<'a, Correspondence>),
    /// Over contour correspondences.
    Contours(slice::Iter<'a, ContourPoint>),
}

impl<'a> Iterator for Items<'a> {
    type Item = Item<'a>;

    fn next(&mut self) -> Option<Item<'a>> {
        match self {
            Items::Points(i) => i.next().map(Item::Point),
            Items::Contours(i) => i.next().map(Item::Contour),
        }
    }
}

/// What applying one measurement gave.
#[derive(Clone, Copy, Debug)]
pub struct Applied<T> {
    /// Distance between the prediction and the measurement before the update (normalised
    /// units; along the normal for a contour), when the point is in front at the prediction.
    pub prediction_error: Option<T>,
    /// Normalised residual `s_i` (eq. 17), infinite when it cannot be computed.
    pub nis: T,
    /// Whether it was applied.
    pub result: Result<(), Rejection>,
}

impl Item<'_> {
    /// Measures the prediction error against `predicted`, then updates `st` by this
    /// measurement (gated, eq. 17).
    pub fn apply<T: Kernels>(
        self,
        st: &mut State<T>,
        predicted: &StateVec<T>,
        prm: &Params<T>,
    ) -> Applied<T> {
        let he = &prm.hand_eye;
        let (prediction_error, (nis, result)) = match self {
            Item::Point(c) => {
                let obs = Observation::<T>::from_wire(c);
                let error = correspondence::project(predicted, he, &obs.m_w)
                    .map(|proj| (proj - obs.m_n).norm());
                (error, correspondence::update(st, prm, &obs))
            }
            Item::Contour(c) => {
                let obs = ContourObservation::<T>::from_wire(c);
                let error = obs.offset(predicted, he).map(|e| e.abs());
                (error, contour::update(st, prm, &obs))
            }
        };
        Applied {
            prediction_error,
            nis,
            result,
        }
    }
}
