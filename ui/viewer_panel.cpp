#include "viewer_panel.h"

#include <GLFW/glfw3.h>
#include <GL/gl.h>
#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "atlas_panel.h"
#include "gl_texture.h"
#include "studio_context.h"

namespace refocus {

namespace {

// The time slice shows what the viewer shows: through the lens when the mode, or a side of the
// split wipe, is refocused.
bool shows_refocused(const ViewerState& v) {
    return v.mode->refocused || (v.mode->wipe && (v.split_a->refocused || v.split_b->refocused));
}

bool image_pixel(const ViewerState& v, const StudioContext& ctx, float sx, float sy, int& x,
                 int& y) {
    if (v.img_w <= 0 || !ctx.source) return false;
    const float u = (sx - v.img_x) / v.img_w, w = (sy - v.img_y) / v.img_h;
    if (u < 0 || u >= 1 || w < 0 || w >= 1) return false;
    x = static_cast<int>(u * ctx.source->width());
    y = static_cast<int>(w * ctx.source->height());
    return true;
}

// The mode bar, zoom, the time slice's switch and, in split mode, the wipe's sides.
void draw_mode_bar(ViewerState& v, StudioContext& ctx) {
    const auto& modes = view_modes();
    for (size_t i = 0; i < modes.size(); ++i) {
        if (i) ImGui::SameLine();
        if (ImGui::RadioButton(modes[i].label, v.mode == &modes[i])) {
            v.mode = &modes[i];
            ctx.view_dirty = true;
            refresh_view(v, ctx);
        }
    }
    ImGui::SameLine();
    ImGui::SetNextItemWidth(110);
    ImGui::SliderFloat("zoom", &v.zoom, 0.0f, 8.0f, v.zoom == 0 ? "fit" : "%.2fx");
    ImGui::SameLine();
    if (ImGui::Checkbox("time slice", &v.slice.on)) v.slice.dirty = true;
    if (!v.mode->wipe) return;
    std::vector<const char*> labels;
    for (const ViewModeInfo& m : modes) labels.push_back(m.label);
    const int n = static_cast<int>(modes.size());
    int a = static_cast<int>(v.split_a - modes.data()),
        b = static_cast<int>(v.split_b - modes.data());
    ImGui::SetNextItemWidth(110);
    bool ch = ImGui::Combo("left", &a, labels.data(), n);
    ImGui::SameLine();
    ImGui::SetNextItemWidth(110);
    ch |= ImGui::Combo("right", &b, labels.data(), n);
    ImGui::SameLine();
    ImGui::SetNextItemWidth(160);
    ch |= ImGui::SliderFloat("wipe", &v.split, 0.0f, 1.0f);
    if (ch && !modes[a].wipe && !modes[b].wipe) {
        v.split_a = &modes[a];
        v.split_b = &modes[b];
        refresh_view(v, ctx);
    }
}

// Wheel zooms (from "fit" on), middle or right drag pans.
void zoom_and_pan(ViewerState& v, float scale) {
    const ImGuiIO& io = ImGui::GetIO();
    if (io.MouseWheel != 0.0f)
        v.zoom =
            std::clamp((v.zoom > 0 ? v.zoom : scale) * std::pow(1.15f, io.MouseWheel), 0.1f, 16.0f);
    if (ImGui::IsMouseDragging(ImGuiMouseButton_Middle) ||
        ImGui::IsMouseDragging(ImGuiMouseButton_Right)) {
        ImGui::SetScrollX(ImGui::GetScrollX() - io.MouseDelta.x);
        ImGui::SetScrollY(ImGui::GetScrollY() - io.MouseDelta.y);
    }
}

// The pixel under the pointer, what a click does there, and the click itself.
std::optional<ViewerClick> hover_image(ViewerState& v, StudioContext& ctx) {
    int x, y;
    const ImVec2 mp = ImGui::GetMousePos();
    if (!image_pixel(v, ctx, mp.x, mp.y, x, y)) return std::nullopt;
    std::string tip = "pixel " + std::to_string(x) + ", " + std::to_string(y);
    if (ctx.depth && ctx.view_at_playhead()) {
        const FrameMaps& m = ctx.view->maps;
        char b[64];
        std::snprintf(b, sizeof b, "\ninverse depth %.2f",
                      ctx.depth->depth_at_pixel(ctx.frame, x, y, m.uv_bg, m.uv_fg, m.alpha));
        tip += b;
    }
    if (v.pick == ViewerState::Pick::Focus) tip += "\nclick: focus here at this frame";
    if (v.pick == ViewerState::Pick::Track) tip += "\nclick: track this point";
    ImGui::SetTooltip("%s", tip.c_str());
    if (!ImGui::IsMouseClicked(0)) return std::nullopt;
    if (v.slice.on) {
        v.slice.row = y;
        v.slice.dirty = true;
    }
    const ViewerState::Pick pick = v.pick;
    v.pick = ViewerState::Pick::None;
    if (pick == ViewerState::Pick::None) return std::nullopt;
    return ViewerClick{pick, x, y};
}

// The image, centred, at the zoom; returns a click while a pick is armed.
std::optional<ViewerClick> draw_image(ViewerState& v, StudioContext& ctx, ImVec2 avail) {
    const float scale =
        v.zoom > 0 ? v.zoom : std::min(avail.x / v.tex_w, std::max(avail.y, 1.0f) / v.tex_h);
    const ImVec2 isz(v.tex_w * scale, v.tex_h * scale);
    ImGui::BeginChild("image", avail, false,
                      ImGuiWindowFlags_HorizontalScrollbar | ImGuiWindowFlags_NoScrollWithMouse);
    const ImVec2 cur = ImGui::GetCursorScreenPos(), region = ImGui::GetContentRegionAvail();
    ImGui::SetCursorScreenPos(ImVec2(cur.x + std::max(0.0f, (region.x - isz.x) * 0.5f),
                                     cur.y + std::max(0.0f, (region.y - isz.y) * 0.5f)));
    const ImVec2 ip = ImGui::GetCursorScreenPos();
    ImGui::Image(reinterpret_cast<ImTextureID>(static_cast<intptr_t>(v.tex)), isz);
    v.img_x = ip.x, v.img_y = ip.y, v.img_w = isz.x, v.img_h = isz.y;
    if (ImGui::IsWindowHovered()) zoom_and_pan(v, scale);
    std::optional<ViewerClick> click;
    if (ImGui::IsItemHovered()) click = hover_image(v, ctx);
    if (v.slice.on) {
        // The row the slice is taken from.
        const float ry = ip.y + (v.slice.row + 0.5f) * isz.y / v.tex_h;
        ImGui::GetWindowDrawList()->AddLine(ImVec2(ip.x, ry), ImVec2(ip.x + isz.x, ry),
                                            IM_COL32(255, 200, 0, 160));
    }
    ImGui::EndChild();
    return click;
}

// Instead of the image: a project being made or copied, or none open. True when shown.
bool draw_placeholder(StudioContext& ctx) {
    if (ctx.busy_with_files()) {
        if (!ctx.save_as_dir.empty())
            ImGui::Text("Saving the project as %s: copying its files ...", ctx.save_as_dir.c_str());
        else
            ImGui::Text("Making the project %s: decoding the clip's frames ...",
                        ctx.ingest_dir.c_str());
        ImGui::ProgressBar(static_cast<float>(ctx.worker->status().job_progress), ImVec2(400, 0));
        return true;
    }
    if (!ctx.source) {
        // The buttons leave a request that the studio runs next frame through its own dialogs
        // (file_browser.h, included with atlas_panel.h).
        ImGui::TextUnformatted("No project open.");
        ImGui::Spacing();
        if (ImGui::Button("Open project...")) post_start_request({StartRequest::Open, {}});
        item_tooltip(
            "Pick a project folder in the file browser, or a clip: a project is made\n"
            "beside it (File > Open..., Ctrl+O, types a path)");
        ImGui::SameLine();
        if (ImGui::Button("New from clip...")) post_start_request({StartRequest::NewFromClip, {}});
        item_tooltip("Pick a video or an image sequence, then where the new project goes");
        ImGui::TextDisabled("or drop a clip or a project folder onto this window");
        const std::vector<std::string>& recent = browser_places().recent;
        if (!recent.empty()) {
            ImGui::Spacing();
            ImGui::TextDisabled("Recent projects");
        }
        for (const std::string& r : recent) {
            if (ImGui::Selectable(r.c_str(), false, 0, ImVec2(ImGui::CalcTextSize(r.c_str()).x, 0)))
                post_start_request({StartRequest::OpenPath, r});
            item_tooltip("Open this project");
        }
        return true;
    }
    return false;
}

}  // namespace

void set_view_mode(ViewerState& v, StudioContext& ctx, const ViewModeInfo& mode) {
    v.mode = &mode;
    v.show_atlas = false;
    ctx.view_dirty = true;
}

void poll_fit_output(ViewerState& v, AtlasPanel& atlas, StudioContext& ctx) {
    if (!ctx.doc.is_open()) return;
    const FitWorker::Status st = ctx.worker->status();
    const bool fitted = st.state == FitWorker::State::Ready ||
                        st.state == FitWorker::State::Fitting ||
                        st.state == FitWorker::State::Paused;
    if (!fitted) return;
    const double now = glfwGetTime();
    // Atlases: on every version change when idle, at most every 2 s while fitting.
    const bool fitting = st.state == FitWorker::State::Fitting;
    if (st.snap.atlas_version != ctx.atlas_version &&
        (!fitting || now - ctx.last_refresh_request > 2.0)) {
        ctx.last_refresh_request = now;
        ctx.atlas_version = st.snap.atlas_version;
        ctx.worker->request_atlases();
        ctx.requested_frame = -1;  // the frame must be rendered again too
        ctx.view_dirty = true;
    }
    if (auto a = ctx.worker->take_atlases()) {
        atlas.set_bases(a->bg, a->fg);
        ctx.edit_version = -1;  // re-upload to the preview
        ctx.view_dirty = true;
    }
    if (ctx.view_dirty && ctx.requested_frame != ctx.frame) {
        ctx.worker->request_frame(ctx.frame);
        ctx.requested_frame = ctx.frame;
    }
    if (auto f = ctx.worker->take_frame()) {
        ctx.view = std::move(*f);
        if (ctx.view->t == ctx.requested_frame) ctx.requested_frame = -1;
        if (ctx.view_at_playhead()) refresh_view(v, ctx);
    }
    // Depth: needed by refocus, depth view, click-to-focus; fitted once per checkpoint.
    if (!ctx.depth_requested && !fitting) {
        ctx.worker->request_depth();
        ctx.depth_requested = true;
    }
    auto d = ctx.worker->depth();
    if (d != ctx.depth) {
        ctx.depth = d;
        ctx.view_dirty = true;
        if (ctx.view_at_playhead()) refresh_view(v, ctx);
    }
    if (!fitting && st.snap.atlas_version != ctx.atlas_version) ctx.depth_requested = false;
    if (ctx.edit_version != ctx.edits_version()) {
        ctx.view_dirty = true;
        if (ctx.view_at_playhead()) refresh_view(v, ctx);
    }
}

void refresh_view(ViewerState& v, StudioContext& ctx) {
    if (!ctx.source) return;
    try {
        upload_texture(v.tex, v.mode->render(v, ctx), v.tex_w, v.tex_h);
    } catch (const std::exception& e) {
        upload_texture(v.tex, ctx.source->linear(ctx.frame), v.tex_w, v.tex_h);
        ctx.info = e.what();
    }
    ctx.view_dirty = v.mode->needs_fit && !ctx.view_at_playhead();
    v.slice.dirty = true;
}

std::optional<ViewerClick> draw_viewer(ViewerState& v, AtlasPanel& atlas, StudioContext& ctx) {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    const ImVec2 size(vp->WorkSize.x - kSidePanelWidth, vp->WorkSize.y - kTimelineHeight);
    ImGui::SetNextWindowPos(vp->WorkPos);
    ImGui::SetNextWindowSize(size);
    if (v.show_atlas) {
        if (atlas.draw()) ctx.changed();  // a stroke, an undo, an import
        return std::nullopt;
    }
    ImGui::Begin("Viewer", nullptr,
                 ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_NoMove |
                     ImGuiWindowFlags_NoBringToFrontOnFocus | ImGuiWindowFlags_NoSavedSettings);
    if (draw_placeholder(ctx)) {
        ImGui::End();
        return std::nullopt;
    }
    draw_mode_bar(v, ctx);
    if (ctx.view_dirty && (!v.mode->needs_fit || ctx.view_at_playhead())) refresh_view(v, ctx);
    if (!v.tex) refresh_view(v, ctx);
    ImVec2 avail = ImGui::GetContentRegionAvail();
    const float slice_h = v.slice.on ? std::min(avail.y * 0.35f, 160.0f) : 0.0f;
    avail.y -= slice_h;
    const std::optional<ViewerClick> click = draw_image(v, ctx, avail);
    if (v.slice.on) {
        const bool output = v.mode->needs_fit && ctx.worker->has_engine();
        if (v.slice.dirty)
            rebuild_time_slice(v.slice, ctx, output, output && ctx.depth && shows_refocused(v));
        poll_time_slice(v.slice);
        draw_time_slice(v.slice, ctx, avail.x, slice_h);
    }
    ImGui::End();
    return click;
}

void release_viewer(ViewerState& v) {
    if (v.tex) glDeleteTextures(1, &v.tex);
    v.tex = 0;
    release_time_slice(v.slice);
}

}  // namespace refocus
