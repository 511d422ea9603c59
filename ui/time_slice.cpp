#include "time_slice.h"

#include <GL/gl.h>
#include <imgui.h>

#include <algorithm>

#include "edit/recompose.h"
#include "fit/fit_engine.h"
#include "io/tensor_image.h"
#include "gl_texture.h"
#include "studio_context.h"

namespace refocus {

namespace {
// The output's slice, rendered on the worker from every frame's layers (the CPU twin for the
// lens), with the artist's atlas edits, saved or not, as the viewer and the export show them.
void post_output_slice(StudioContext& ctx, std::shared_ptr<TimeSliceState::Job> job, int row,
                       std::shared_ptr<const DepthModel> depth) {
    const int w = ctx.source->width(), n = ctx.source->frames();
    const FocusTrack focus = ctx.doc.focus();
    const Image bg_edit = ctx.doc.edits().bg.has_edits() ? ctx.doc.edits().bg.result() : Image();
    const Image fg_edit = ctx.doc.edits().fg.has_edits() ? ctx.doc.edits().fg.result() : Image();
    ctx.worker->post("time slice", [job, row, depth, focus, w, n, bg_edit, fg_edit](
                                       FitEngine* engine, const Project&) {
        if (!engine) return;
        torch::Tensor d_bg, d_fg;
        {
            std::lock_guard<std::mutex> lock(engine->model_mutex());
            auto delta = [](const Image& edit, const torch::Tensor& base) {
                if (edit.empty() || !base.defined()) return torch::Tensor();
                auto e = image_to_tensor(edit).narrow(0, 0, 3);
                if (e.sizes() != base.sizes()) return torch::Tensor();  // an atlas of another fit
                return (e - base).unsqueeze(0);
            };
            d_bg = delta(bg_edit, engine->model().atlas_bg());
            d_fg = delta(fg_edit, engine->model().atlas_fg());
        }
        Image s(w, n, 3);
        for (int t = 0; t < n; ++t) {
            const FrameMaps m = frame_maps(*engine, t, d_bg, d_fg);
            const Image f =
                depth ? render_refocused(m, *depth, t, focus.lens_at(t, depth.get()), 2) : m.sharp;
            for (int x = 0; x < w; ++x)
                for (int c = 0; c < 3; ++c) s.at(x, t, c) = f.at(x, row, c);
        }
        std::lock_guard<std::mutex> lk(job->mutex);
        job->image = std::move(s);
        job->done = true;
    });
}
// The input's slice: one row of every frame of the cache, read on the worker (file I/O stays
// off the UI thread).
void post_input_slice(StudioContext& ctx, std::shared_ptr<TimeSliceState::Job> job, int row) {
    const int w = ctx.source->width(), n = ctx.source->frames();
    ctx.worker->post("time slice", [job, row, w, n](FitEngine*, const Project& project) {
        Image s(w, n, 3);
        for (int t = 0; t < n; ++t) {
            const Image f = project.read_frame(t);
            for (int x = 0; x < w; ++x)
                for (int c = 0; c < 3; ++c)
                    s.at(x, t, c) = f.at(x, row, std::min(c, f.channels - 1));
        }
        std::lock_guard<std::mutex> lk(job->mutex);
        job->image = std::move(s);
        job->done = true;
    });
}
}  // namespace

void rebuild_time_slice(TimeSliceState& s, StudioContext& ctx, bool output, bool refocus) {
    if (s.row < 0 || s.row >= ctx.source->height()) s.row = ctx.source->height() / 2;
    const int64_t edit_version = ctx.edits_version();
    std::string key =
        std::to_string(s.row) + (output ? (refocus ? "/refocus/" : "/sharp/") : "/input/") +
        std::to_string(ctx.atlas_version) + "/" + std::to_string(output ? edit_version : 0);
    if (refocus) key += ctx.doc.focus().to_json().dump();
    s.dirty = false;
    if (key == s.key) return;
    s.key = key;
    auto job = std::make_shared<TimeSliceState::Job>();
    job->key = key;
    s.job = job;
    if (output)
        post_output_slice(ctx, job, s.row, refocus ? ctx.depth : nullptr);
    else
        post_input_slice(ctx, job, s.row);
}

void poll_time_slice(TimeSliceState& s) {
    if (!s.job) return;
    std::lock_guard<std::mutex> lk(s.job->mutex);
    if (!s.job->done) return;
    if (s.job->key == s.key) {
        upload_texture(s.tex, s.job->image, s.tex_w, s.tex_h);
        s.image = std::move(s.job->image);
        s.label = s.key.find("/refocus/") != std::string::npos ? "refocused"
                  : s.key.find("/sharp/") != std::string::npos ? "sharp"
                                                               : "input";
    }
    s.job.reset();
}

void draw_time_slice(TimeSliceState& s, StudioContext& ctx, float width, float height) {
    ImGui::Text("time slice: %s row %d over %d frames%s (click the image to choose the row)",
                s.label.c_str(), s.row, ctx.source->frames(), s.job ? ", rendering ..." : "");
    const float h = height - ImGui::GetFrameHeightWithSpacing();
    ImGui::Image(reinterpret_cast<ImTextureID>(static_cast<intptr_t>(s.tex)),
                 ImVec2(std::min(width, h * s.tex_w / std::max(1, s.tex_h) * 3), h));
}

void release_time_slice(TimeSliceState& s) {
    if (s.tex) glDeleteTextures(1, &s.tex);
    s.tex = 0;
}

}  // namespace refocus
