#pragma once
// Camera motion: one homography per frame to a reference frame, from features tracked between
// consecutive frames (Shi-Tomasi corners + pyramidal Lucas-Kanade, forward-backward checked,
// RANSAC), chained. When a pair has too few features the pair's homography is fitted to the
// consistent dense flow instead, and failing that it is the identity; each fallback is logged.
#include <array>
#include <string>
#include <vector>

#include "io/image.h"
#include "prepare/flow.h"
#include "prepare/log.h"

namespace refocus {

// 3x3 projective map, row-major, normalised so that m[8] = 1. Maps pixel coordinates with
// centres at integers: (x', y', w') = M (x, y, 1), result (x'/w', y'/w').
struct Homography {
    std::array<double, 9> m{1, 0, 0, 0, 1, 0, 0, 0, 1};

    static Homography identity() { return {}; }
    void apply(double x, double y, double& ox, double& oy) const;
    Homography operator*(const Homography& o) const;  // (this ∘ o)(p) = this(o(p))
    Homography inverse() const;                       // throws refocus::Error when singular
};

// Largest distance any of the four frame corners moves under h (px): the "is it identity" test.
double max_corner_displacement(const Homography& h, int width, int height);

struct MotionOptions {
    int reference = 0;       // frame the homographies map to
    int max_features = 600;  // Shi-Tomasi corners per frame (spread over the grid below)
    int feature_grid_x = 8, feature_grid_y = 6;  // corners are found per cell of this grid
    double feature_quality_cell = 0.05;          // relative to the cell's best corner
    double feature_min_distance = 4.0;
    double track_fb_max_px = 0.5;  // LK forward-backward disagreement allowed
    double ransac_px = 1.0;        // RANSAC reprojection threshold
    double ring_ransac_px = 0.5;   // the same for the consensus of the frame's outer ring
    int min_affine_tracks = 100;   // fewer agreeing tracks: the pair is a translation, ...
    int weak_pair_reach = 3;       // ... interpolated from well-tracked pairs this many frames away
    int min_inliers = 12;          // fewer → fall back to the flow, then to identity
    double static_max_px = 0.5;    // camera is static if no corner moves more than this
    // A camera read as moving is tested again on the still part of the frame (prepare.cpp),
    // where at least this share of the frame's edge does not move: a subject that fills much of
    // the frame otherwise drags the estimate along.
    bool background_only = true;
    double still_ring_share = 0.5;
};

struct CameraMotion {
    int reference = 0;
    std::vector<Homography> to_reference;  // [t]: frame t → reference frame
    std::vector<Homography> pair;          // [t]: frame t+1 → frame t
    std::vector<std::string> pair_source;  // [t]: "features", "flow" or "identity"
    std::vector<int> pair_inliers;         // [t]: RANSAC inliers behind pair[t]
    bool is_static = false;                // every to_reference moves corners < static_max_px
    double max_displacement_px = 0.0;      // the largest such corner motion
};

// `flow` (may be null) serves the fallback. Frames: linear RGB, one size. With `subject`
// (per-frame masks, > 0.1 inside), no feature on or near the subject is tracked: the camera's
// motion is the background's.
CameraMotion estimate_camera_motion(const std::vector<Image>& frames, const ClipFlow* flow,
                                    const MotionOptions& opts, PrepareLog& log,
                                    const std::vector<Image>* subject = nullptr);

// The flow the homography predicts: h_ab maps frame a to frame b, so f(x) = h_ab(x) − x.
// 2-channel image of size width x height.
Image homography_flow(const Homography& h_ab, int width, int height);

}  // namespace refocus
