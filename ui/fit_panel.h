#pragma once
// The Fit tab: preset, budget, seed, radius maps and masks; start, continue, pause and stop;
// the live loss and reblur PSNR with the ETA.
#include "project/project.h"

namespace refocus {

struct StudioContext;

struct FitPanelState {
    int preset = 0;  // index into studio_preset_names()
    float budget_minutes = 5.0f;
    int budget_iters = 200;
    bool use_iters = false;
    int seed = 1;
    char coc_path[1024] = {0}, mask_path[1024] = {0};
};

// The project's saved fit settings, as the panel shows them; a fitted project's budget (the
// checkpoint's running total) is not shown: the budget fields say what a run adds.
void load_fit_panel(FitPanelState& s, const Project& project);
// Starts the fit with the panel's settings (the script's "fit" too): from scratch, or going on
// from the checkpoint with `resume`.
void start_fit(const FitPanelState& s, StudioContext& ctx, bool resume);
void draw_fit_panel(FitPanelState& s, StudioContext& ctx);

}  // namespace refocus
