#pragma once
// The viewer's time slice: one image row over all frames (x → column, y → frame), where flicker
// shows as horizontal streaks. The input's slice is read on the UI thread; the sharp or
// refocused output's is rendered by the worker and shown when it arrives.
#include <memory>
#include <mutex>
#include <string>

#include "io/image.h"

namespace refocus {

struct StudioContext;

struct TimeSliceState {
    bool on = false;
    int row = -1;  // -1: the middle row
    bool dirty = true;
    struct Job {
        std::mutex mutex;
        bool done = false;
        Image image;  // linear, width x frames
        std::string key;
    };
    std::shared_ptr<Job> job;  // the worker's render in flight
    std::string key, label = "input";
    Image image;  // what the texture shows (linear RGB)
    unsigned tex = 0;
    int tex_w = 0, tex_h = 0;
};

// Starts the slice of what the viewer shows: the fit's output (`output`), through the lens
// (`refocused`), or the input. Nothing happens when the slice shown is already that one.
void rebuild_time_slice(TimeSliceState& s, StudioContext& ctx, bool output, bool refocused);
// Takes the worker's slice when it is done.
void poll_time_slice(TimeSliceState& s);
// The caption and the slice's image under the viewer's image, `height` px tall in all.
void draw_time_slice(TimeSliceState& s, StudioContext& ctx, float width, float height);
void release_time_slice(TimeSliceState& s);  // its GL texture

}  // namespace refocus
