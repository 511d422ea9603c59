#include "export_panel.h"

#include <GLFW/glfw3.h>

#include <imgui.h>

#include <algorithm>
#include <cstdio>
#include <iterator>

#include "session/fit_session.h"
#include "studio_context.h"
#include "util/error.h"

namespace refocus {

namespace {

// The export panel's passes, in its checkbox order.
struct PassInfo {
    const char* label;
    const char* name;  // export_pass name
    const char* tip;
};
const PassInfo kPasses[] = {
    {"sharp plate", "sharp", "The all-in-focus frames, with the atlas edits"},
    {"refocused video", "refocus", "The frames through the keyed lens (Focus tab)"},
    {"atlases (edited)", "atlas", "The background and foreground atlases with the paint"},
    {"alpha", "alpha", "The foreground layer's matte per frame"},
    {"radius (CoC)", "coc", "The blur radius the fit uses per pixel, px (EXR)"},
    {"inverse depth", "depth", "The fitted inverse depth per pixel (EXR)"},
    {"UV maps", "uv", "Where each pixel samples the atlases (EXR)"},
    {"reblur", "reblur", "The model's re-blurred frames, to compare with the input"},
    {"confidence", "confidence",
     "1 where the sharp plate comes from the fit, 0 where it falls back to the shot"},
    {"optical flow", "flow", "Forward flow to the next frame from the fitted mappings, px (EXR)"},
    {"parallax", "parallax",
     "The background's parallax over its atlas (EXR), where it was fitted with fast.parallax"}};
constexpr int kPassCount = int(std::size(kPasses));
static_assert(kPassCount == int(sizeof(ExportPanelState::pass) / sizeof(bool)),
              "a checkbox a pass");
const char* kFormats[] = {"png", "tiff", "exr", "mp4"};

struct ExportJob {
    std::vector<std::string> passes;
    std::string format, out;
    int first = 0, last = 0;
    double fps = 0;
    // The document as it is now, saved or not.
    std::shared_ptr<ProjectEdits> edits;
    std::shared_ptr<Project> project;
    std::shared_ptr<FocusTrack> focus;
};

// Runs on the worker: each pass into its own folder (or .mp4), the maps always as EXR.
std::string run_export(FitEngine& engine, const ExportJob& job, FitWorker& w) {
    int files = 0;
    for (size_t i = 0; i < job.passes.size(); ++i) {
        const ExportPass pass = parse_export_pass(job.passes[i]);
        std::string fmt = job.format;
        if (is_data_pass(pass) || pass == ExportPass::Parallax) fmt = "exr";
        if (pass == ExportPass::Atlas && fmt == "mp4") fmt = "png";
        std::string target = job.out;
        if (fmt == "mp4")
            target = (fs::path(job.out) / (job.passes[i] + ".mp4")).string();
        else if (pass != ExportPass::Atlas)
            target = (fs::path(job.out) / job.passes[i]).string();
        if (job.project) check_export_target(*job.project, target);  // before any folder is made
        fs::create_directories(
            fs::path(fmt == "mp4" ? fs::path(target).parent_path() : fs::path(target)));
        ExportOptions eo;
        eo.fps = job.fps;
        eo.project = job.project.get();
        eo.edits = job.edits.get();
        eo.focus = job.focus.get();
        eo.first = job.first;
        eo.last = job.last;
        eo.progress = [&](int done, int total) {
            w.set_job_progress((i + double(done) / total) / job.passes.size());
            return !w.cancelled();
        };
        auto written = export_pass(engine, pass, fmt, target, eo);
        files += static_cast<int>(written.size());
    }
    return "exported " + std::to_string(files) + " files to " + job.out;
}

}  // namespace

void reset_export_panel(ExportPanelState& s, StudioContext& ctx) {
    s.first = 0;
    s.last = ctx.source->frames() - 1;
    if (s.out[0] == 0)
        std::snprintf(s.out, sizeof s.out, "%s",
                      (ctx.doc.project().dir / "export").string().c_str());
}

void start_export(ExportPanelState& s, StudioContext& ctx, const nlohmann::json& req) {
    if (!ctx.doc.is_open()) throw Error("no project is open");
    if (!ctx.worker->has_engine()) throw Error("fit the project before exporting (Fit tab)");
    if (s.running) throw Error("an export is already running");
    auto job = std::make_shared<ExportJob>();
    job->passes = req.at("what").get<std::vector<std::string>>();
    job->format = req.value("format", "png");
    // Absolute, so that the result line says where the files went.
    job->out = fs::absolute(req.at("out").get<std::string>()).lexically_normal().string();
    const int n = ctx.source->frames();
    job->first = req.value("first", 0), job->last = req.value("last", n - 1);
    if (job->first < 0 || job->first > job->last || job->last >= n)
        throw Error("export range " + std::to_string(job->first) + ".." +
                    std::to_string(job->last) + " is outside the clip's frames 0.." +
                    std::to_string(n - 1));
    for (const auto& p : job->passes) parse_export_pass(p);  // refuse unknown passes now
    job->edits = std::make_shared<ProjectEdits>(ctx.doc.edits());
    job->project = std::make_shared<Project>(ctx.doc.project());
    job->focus = std::make_shared<FocusTrack>(ctx.doc.focus());
    job->fps = ctx.source->fps();
    s.running = true;
    s.started = glfwGetTime();
    s.result.clear();
    FitWorker* w = ctx.worker.get();
    ctx.worker->post("export", [job, w](FitEngine* engine, const Project&) {
        std::string result;
        try {
            if (!engine) throw Error("the project has no fit to export");
            result = run_export(*engine, *job, *w);
        } catch (const std::exception& e) {
            result = std::string("export failed: ") + e.what();
        }
        w->post_result(result);
    });
}

void draw_export_panel(ExportPanelState& s, StudioContext& ctx) {
    if (!ctx.doc.is_open()) {
        ImGui::TextWrapped("Open a project first.");
        return;
    }
    const FitWorker::Status st = ctx.worker->status();
    ImGui::BeginDisabled(s.running);
    for (int i = 0; i < kPassCount; ++i) {
        ImGui::Checkbox(kPasses[i].label, &s.pass[i]);
        item_tooltip(kPasses[i].tip);
    }
    ImGui::Combo("format", &s.format, kFormats, 4);
    item_tooltip("png / tiff (16-bit) / exr (half float) image sequences, or an mp4 video");
    ImGui::TextDisabled("radius, depth, UV and flow are written as EXR; atlases as images");
    const int n = ctx.source ? ctx.source->frames() : 1;
    if (s.last < 0) s.last = n - 1;
    if (ctx.in_frame != s.seen_in || ctx.out_frame != s.seen_out) {
        // New in/out points on the timeline (I, O): the range follows them, as in an editor.
        s.seen_in = ctx.in_frame, s.seen_out = ctx.out_frame;
        s.first = ctx.first_frame(), s.last = ctx.last_frame();
    }
    int range[2] = {s.first, s.last};
    if (ImGui::DragInt2("frames", range, 0.2f, 0, n - 1)) {
        s.first = std::clamp(std::min(range[0], range[1]), 0, n - 1);
        s.last = std::clamp(std::max(range[0], range[1]), 0, n - 1);
    }
    item_tooltip("First and last frame to export; follows the timeline's in and out points (I, O)");
    ImGui::SetNextItemWidth(200);
    ImGui::InputText("folder", s.out, sizeof s.out);
    item_tooltip("The folder the passes are written to (one folder or .mp4 per pass)");
    ImGui::SameLine();
    if (ImGui::Button("Browse...")) {
        const fs::path out = fs::absolute(s.out);
        BrowseOptions o;
        o.mode = BrowseMode::Folder;
        o.title = "Export folder";
        o.ok = "Choose";
        o.dir = out.parent_path().string();
        o.name = out.filename().string();
        s.browser.open(o);
    }
    item_tooltip("Pick the export folder, or name a new one, in the file browser");
    if (ImGui::Button("Export")) {
        nlohmann::json req = {
            {"format", kFormats[s.format]}, {"out", s.out}, {"first", s.first}, {"last", s.last}};
        std::vector<std::string> what;
        for (int i = 0; i < kPassCount; ++i)
            if (s.pass[i]) what.push_back(kPasses[i].name);
        req["what"] = what;
        ctx.guarded([&] { start_export(s, ctx, req); });
    }
    item_tooltip("Write the checked passes for the frame range (runs on the worker)");
    ImGui::EndDisabled();
    if (s.running) {
        // Elapsed and a linear ETA from the fraction done, as the fit's bar shows them.
        const double p = st.job_progress, el = glfwGetTime() - s.started;
        char label[96];
        if (p > 0.01)
            std::snprintf(label, sizeof label, "%.0f%%  elapsed %d:%02d  ETA %d:%02d", 100 * p,
                          int(el) / 60, int(el) % 60, int(el * (1 - p) / p) / 60,
                          int(el * (1 - p) / p) % 60);
        else
            std::snprintf(label, sizeof label, "starting  elapsed %d:%02d", int(el) / 60,
                          int(el) % 60);
        ImGui::ProgressBar(static_cast<float>(p), ImVec2(-1, 0), label);
        if (ImGui::Button("Cancel")) ctx.worker->cancel_job();
        item_tooltip("Stop the export; a sequence left incomplete is removed");
        ImGui::TextDisabled("files are complete or absent: a cancelled sequence is removed");
    }
    if (!s.result.empty()) ImGui::TextWrapped("%s", s.result.c_str());
    if (s.browser.draw() == BrowseEvent::Picked)
        std::snprintf(s.out, sizeof s.out, "%s", s.browser.picked().c_str());
}

}  // namespace refocus
