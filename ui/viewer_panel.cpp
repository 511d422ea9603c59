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
        if (ImGui::RadioButton(modes[i].label, v.mode == &modes[i]))
            set_view_mode(v, ctx, modes[i]);
        if (ImGui::IsItemHovered()) ImGui::SetTooltip("%s", modes[i].tooltip);
    }
    ImGui::SameLine();
    ImGui::SetNextItemWidth(110);
    ImGui::SliderFloat("zoom", &v.zoom, 0.0f, 8.0f, v.zoom == 0 ? "fit" : "%.2fx");
    if (ImGui::IsItemHovered()) ImGui::SetTooltip("0 fits the window; the mouse wheel zooms too");
    ImGui::SameLine();
    if (ImGui::Checkbox("time slice", &v.slice.on)) v.slice.dirty = true;
    if (ImGui::IsItemHovered())
        ImGui::SetTooltip(
            "One image row over all frames: flicker shows as streaks. Click the "
            "image to pick the row");
    if (!v.mode->wipe) return;
    std::vector<const char*> labels;
    for (const ViewModeInfo& m : modes) labels.push_back(m.label);
    const int n = static_cast<int>(modes.size());
    int a = static_cast<int>(v.split_a - modes.data()),
        b = static_cast<int>(v.split_b - modes.data());
    ImGui::SetNextItemWidth(110);
    bool ch = ImGui::Combo("left", &a, labels.data(), n);
    if (ImGui::IsItemHovered()) ImGui::SetTooltip("The mode left of the wipe");
    ImGui::SameLine();
    ImGui::SetNextItemWidth(110);
    ch |= ImGui::Combo("right", &b, labels.data(), n);
    if (ImGui::IsItemHovered()) ImGui::SetTooltip("The mode right of the wipe");
    ImGui::SameLine();
    ImGui::SetNextItemWidth(160);
    ImGui::SliderFloat("wipe", &v.split, 0.0f, 1.0f);
    if (ImGui::IsItemHovered())
        ImGui::SetTooltip("The wipe's place; dragging it re-renders nothing");
    if (ch && !modes[a].wipe && !modes[b].wipe) {
        v.split_a = &modes[a];
        v.split_b = &modes[b];
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
    const float fw = static_cast<float>(ctx.source->width()),
                fh = static_cast<float>(ctx.source->height());
    const float scale = v.zoom > 0 ? v.zoom : std::min(avail.x / fw, std::max(avail.y, 1.0f) / fh);
    const ImVec2 isz(fw * scale, fh * scale);
    ImGui::BeginChild("image", avail, false,
                      ImGuiWindowFlags_HorizontalScrollbar | ImGuiWindowFlags_NoScrollWithMouse);
    const ImVec2 cur = ImGui::GetCursorScreenPos(), region = ImGui::GetContentRegionAvail();
    ImGui::SetCursorScreenPos(ImVec2(cur.x + std::max(0.0f, (region.x - isz.x) * 0.5f),
                                     cur.y + std::max(0.0f, (region.y - isz.y) * 0.5f)));
    const ImVec2 ip = ImGui::GetCursorScreenPos();
    auto tex_id = [](unsigned t) {
        return reinterpret_cast<ImTextureID>(static_cast<intptr_t>(t));
    };
    ImGui::Image(tex_id(v.a.tex), isz);
    v.img_x = ip.x, v.img_y = ip.y, v.img_w = isz.x, v.img_h = isz.y;
    if (v.mode->wipe && v.b.tex) {
        // Both sides are pictures of their own: moving the wipe only moves where they are cut.
        const float cut = ip.x + v.split * isz.x;
        ImDrawList* dl = ImGui::GetWindowDrawList();
        dl->AddImage(tex_id(v.b.tex), ImVec2(cut, ip.y), ImVec2(ip.x + isz.x, ip.y + isz.y),
                     ImVec2(v.split, 0), ImVec2(1, 1));
        dl->AddLine(ImVec2(cut, ip.y), ImVec2(cut, ip.y + isz.y), IM_COL32(255, 255, 255, 255));
        if (ImGui::IsItemHovered() && std::abs(ImGui::GetMousePos().x - cut) < 6.0f)
            ImGui::SetMouseCursor(ImGuiMouseCursor_ResizeEW);
        if (ImGui::IsItemClicked(0) && v.pick == ViewerState::Pick::None &&
            std::abs(ImGui::GetMousePos().x - cut) < 6.0f)
            v.dragging_wipe = true;
        if (!ImGui::IsMouseDown(0)) v.dragging_wipe = false;
        if (v.dragging_wipe)
            v.split = std::clamp((ImGui::GetMousePos().x - ip.x) / isz.x, 0.0f, 1.0f);
    }
    if (ImGui::IsWindowHovered()) zoom_and_pan(v, scale);
    std::optional<ViewerClick> click;
    if (ImGui::IsItemHovered()) click = hover_image(v, ctx);
    if (v.slice.on) {
        // The row the slice is taken from.
        const float ry = ip.y + (v.slice.row + 0.5f) * isz.y / fh;
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
    ctx.view_current = false;
}

std::vector<int> wanted_modes(const ViewerState& v) {
    if (v.mode->wipe) return {view_mode_index(*v.split_a), view_mode_index(*v.split_b)};
    return {view_mode_index(*v.mode)};
}

namespace {

// Takes what the worker delivered (atlases, depth) and asks for what comes next. Returns true
// when the scene the renderer draws changed.
bool poll_worker(AtlasPanel& atlas, StudioContext& ctx) {
    const FitWorker::Status st = ctx.worker->status();
    const bool fitted = st.state == FitWorker::State::Ready ||
                        st.state == FitWorker::State::Fitting ||
                        st.state == FitWorker::State::Paused;
    bool changed = false;
    if (fitted != ctx.scene.fitted) {
        ctx.scene.fitted = fitted;
        ++ctx.scene.maps_generation;
        changed = true;
    }
    if (!fitted) return changed;
    const double now = glfwGetTime();
    // Atlases: on every version change when idle, at most every 2 s while fitting.
    const bool fitting = st.state == FitWorker::State::Fitting;
    if (st.snap.atlas_version != ctx.atlas_version &&
        (!fitting || now - ctx.last_refresh_request > 2.0)) {
        ctx.last_refresh_request = now;
        ctx.atlas_version = st.snap.atlas_version;
        ctx.worker->request_atlases();
    }
    if (auto a = ctx.worker->take_atlases()) {
        atlas.set_bases(a->bg, a->fg);
        ++ctx.scene.maps_generation;  // the frames' layers come from the new atlases
        ctx.edit_version = -1;
        changed = true;
    }
    // Depth: needed by refocus, depth view, click-to-focus; fitted once per checkpoint.
    if (!ctx.depth_requested && !fitting) {
        ctx.worker->request_depth();
        ctx.depth_requested = true;
    }
    auto d = ctx.worker->depth();
    if (d != ctx.depth) {
        ctx.depth = d;
        changed = true;
    }
    if (!fitting && st.snap.atlas_version != ctx.atlas_version) ctx.depth_requested = false;
    return changed;
}

// Shows the newest picture of `mode` at the playhead in `tex` (kept when there is none yet).
void show_picture(ViewerState::Picture& pic, int mode, StudioContext& ctx) {
    auto f = ctx.renderer->get(mode, ctx.frame);
    if (!f || f == pic.shown) return;
    upload_rgba8(pic.tex, f->rgba.data(), f->width, f->height);
    pic.shown = f;
}

}  // namespace

void poll_fit_output(ViewerState& v, AtlasPanel& atlas, StudioContext& ctx, bool playing) {
    if (!ctx.doc.is_open() || !ctx.renderer) return;
    bool changed = poll_worker(atlas, ctx) || ctx.view_dirty;
    if (ctx.edit_version != ctx.edits_version() && !ctx.doc.edits().bg.base().empty()) {
        // The edited atlases, copied for the renderer (edit over the fit's, paper Fig. 1).
        ctx.edit_version = ctx.edits_version();
        ctx.scene.edits.bg = std::make_shared<const Image>(ctx.doc.edits().bg.result());
        const AtlasEditor& fg = ctx.doc.edits().fg;
        ctx.scene.edits.fg =
            fg.base().empty() ? nullptr : std::make_shared<const Image>(fg.result());
        ctx.scene.edits.version = ctx.edit_version;
        changed = true;
    }
    if (changed) {
        ctx.scene.focus = ctx.doc.focus();
        ctx.scene.depth = ctx.depth;
        ++ctx.scene.generation;
        ctx.renderer->set_scene(ctx.scene);
        ctx.view_dirty = false;
    }
    const FitWorker::State state = ctx.worker->status().state;
    const std::vector<int> modes = wanted_modes(v);
    // Ahead of the playhead only when it pays: playing, or a fit that is not changing the atlases.
    ctx.renderer->set_wanted(modes, ctx.frame, playing || state != FitWorker::State::Fitting);
    show_picture(v.a, modes[0], ctx);
    if (modes.size() > 1) show_picture(v.b, modes[1], ctx);
    bool current = true;
    for (int m : modes) current = current && ctx.renderer->current(m, ctx.frame);
    auto layers = ctx.renderer->layers_at(ctx.frame);
    if (layers) ctx.view = layers;
    ctx.view_current = current && !changed && (!ctx.scene.fitted || layers);
    if (std::string e = ctx.renderer->take_error(); !e.empty()) ctx.info = e;
    if (playing && v.a.shown) ctx.playback.pictures.insert(v.a.shown->hash);
}

std::optional<ViewerClick> draw_viewer(ViewerState& v, AtlasPanel& atlas, StudioContext& ctx) {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    const Layout::Rect r =
        ctx.layout.viewer(vp->WorkPos.x, vp->WorkPos.y, vp->WorkSize.x, vp->WorkSize.y);
    ImGui::SetNextWindowPos(ImVec2(r.x, r.y));
    ImGui::SetNextWindowSize(ImVec2(r.w, r.h));
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
    if (!v.a.tex) {
        ImGui::TextDisabled("rendering frame %d ...", ctx.frame);
        ImGui::End();
        return std::nullopt;
    }
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
    for (ViewerState::Picture* p : {&v.a, &v.b}) {
        if (p->tex) glDeleteTextures(1, &p->tex);
        *p = ViewerState::Picture{};
    }
    release_time_slice(v.slice);
}

}  // namespace refocus
