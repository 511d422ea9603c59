#include "studio/fit_worker.h"

#include <torch/torch.h>

#include <algorithm>
#include <chrono>
#include <cstdio>

#include "io/tensor_image.h"
#include "util/error.h"

namespace refocus {

namespace {
double now_s() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
}
}  // namespace

const char* state_name(FitWorker::State s) {
    switch (s) {
        case FitWorker::State::Empty:
            return "no project";
        case FitWorker::State::Preparing:
            return "preparing";
        case FitWorker::State::Unfitted:
            return "not fitted";
        case FitWorker::State::Ready:
            return "fitted";
        case FitWorker::State::Fitting:
            return "fitting";
        case FitWorker::State::Paused:
            return "paused";
        case FitWorker::State::Failed:
            return "failed";
    }
    return "?";
}

FitWorker::FitWorker() {
    m_thread = std::thread([this] { loop(); });
}

FitWorker::~FitWorker() {
    stop();
    {
        std::lock_guard<std::mutex> lk(m_mutex);
        m_quit = true;
    }
    m_cv.notify_all();
    m_thread.join();
    for (auto& j : m_frame_jobs) j.second.set_value(std::nullopt);  // waiters wake up empty
}

void FitWorker::add_log(const std::string& line) {
    std::lock_guard<std::mutex> lk(m_mutex);
    m_status.log.push_back(line);
    if (m_status.log.size() > 500) m_status.log.erase(m_status.log.begin());
}

void FitWorker::set_state(State s) {
    std::lock_guard<std::mutex> lk(m_mutex);
    m_status.state = s;
}

void FitWorker::set_job_progress(double p) {
    std::lock_guard<std::mutex> lk(m_mutex);
    m_status.job_progress = p;
}

void FitWorker::post_result(const std::string& r) {
    std::lock_guard<std::mutex> lk(m_mutex);
    m_result = r;
    m_status.log.push_back(r);
}

std::optional<std::string> FitWorker::take_result() {
    std::lock_guard<std::mutex> lk(m_mutex);
    auto r = std::move(m_result);
    m_result.reset();
    return r;
}

FitWorker::Status FitWorker::status(bool full) const {
    std::lock_guard<std::mutex> lk(m_mutex);
    Status s;
    if (full) {
        s = m_status;
    } else {
        s.state = m_status.state;
        s.snap = m_status.snap;
        s.error = m_status.error;
        s.busy = m_status.busy;
        s.busy_what = m_status.busy_what;
        s.job_progress = m_status.job_progress;
        s.prep.stage = m_status.prep.stage;
        s.prep_s = m_status.prep_s;
    }
    if (s.state == State::Preparing && !s.prep.stage.empty()) {
        // The steps' shares are rough: once 15% is done, the time it took gives the
        // total; the bar goes on with the clock within a step, never past its end nor back.
        auto& p = s.prep;
        const double now = now_s();
        p.elapsed_s = now - m_prep_t0;
        p.progress = m_step_begin;
        if (m_prep_total_s > 0) {
            const double step_s = (m_step_end - m_step_begin) * m_prep_total_s;
            const double in_step = now - m_step_t0;
            if (step_s > 0)
                p.progress += (m_step_end - m_step_begin) * std::min(1.0, in_step / step_s);
            p.eta_s = std::max(0.0, step_s - in_step) + (1.0 - m_step_end) * m_prep_total_s;
        }
        p.progress = m_prep_shown = std::max(p.progress, m_prep_shown);
    }
    return s;
}

void FitWorker::begin_prep() {
    std::lock_guard<std::mutex> lk(m_mutex);
    m_prep_t0 = m_step_t0 = now_s();
    m_step_begin = m_step_end = m_prep_shown = 0.0;
    m_prep_total_s = -1.0;
    m_status.prep = Status::Preparation{};
    m_status.prep.stage = "starting";
}

void FitWorker::prep_stage(const std::string& name, double begin, double end) {
    std::lock_guard<std::mutex> lk(m_mutex);
    m_status.prep.stage = name;
    m_step_t0 = now_s();
    m_step_begin = std::clamp(begin, 0.0, 1.0);
    m_step_end = std::clamp(end, m_step_begin, 1.0);
    // The first steps are short and their shares the roughest: no estimate from them.
    if (m_step_begin >= 0.15) m_prep_total_s = (m_step_t0 - m_prep_t0) / m_step_begin;
}

double FitWorker::prep_elapsed() const {
    std::lock_guard<std::mutex> lk(m_mutex);
    return now_s() - m_prep_t0;
}

bool FitWorker::has_engine() const {
    std::lock_guard<std::mutex> lk(m_mutex);
    return m_status.state == State::Ready || m_status.state == State::Fitting ||
           m_status.state == State::Paused;
}

bool FitWorker::has_checkpoint() const {
    std::lock_guard<std::mutex> lk(m_mutex);
    return m_has_checkpoint;
}

FitSettings FitWorker::settings() const {
    std::lock_guard<std::mutex> lk(m_mutex);
    return m_settings;
}

std::string FitWorker::project_dir() const {
    std::lock_guard<std::mutex> lk(m_mutex);
    return m_project ? m_project->dir.string() : std::string();
}

std::shared_ptr<const DepthModel> FitWorker::depth() const {
    std::lock_guard<std::mutex> lk(m_mutex);
    return m_depth;
}

void FitWorker::post(const std::string& what, Job job) {
    {
        std::lock_guard<std::mutex> lk(m_mutex);
        m_jobs.emplace_back(what, std::move(job));
    }
    m_cv.notify_all();
}

void FitWorker::run_job(const std::string& what, const Job& job) {
    {
        std::lock_guard<std::mutex> lk(m_mutex);
        m_status.busy = true;
        m_status.busy_what = what;
        m_status.job_progress = 0.0;
    }
    m_cancel = false;
    try {
        static const Project kNone;
        job(m_engine.get(), m_project ? *m_project : kNone);
    } catch (const std::exception& e) {
        std::lock_guard<std::mutex> lk(m_mutex);
        m_status.error = what + ": " + e.what();
        m_status.log.push_back("error: " + m_status.error);
        if (m_status.state == State::Preparing)
            m_status.state = m_engine ? State::Ready : State::Failed;
    }
    std::lock_guard<std::mutex> lk(m_mutex);
    m_status.busy = false;
    m_status.busy_what.clear();
}

void FitWorker::open(const Project& project) {
    stop();
    set_state(State::Preparing);  // at once, so that the UI and scripts see the pending work
    begin_prep();
    post("open", [this, project](FitEngine*, const Project&) {
        m_engine.reset();
        {
            std::lock_guard<std::mutex> lk(m_mutex);
            m_project = std::make_unique<Project>(project);
            m_settings = read_fit_settings(project);
            m_has_checkpoint = FitEngine::has_checkpoint(fit_dir(project));
            m_depth.reset();
            m_depth_step = -1;
            m_status = Status{};
            m_status.state = State::Preparing;
        }
        add_log("opened " + project.dir.string());
        if (!m_has_checkpoint) {
            set_state(State::Unfitted);
            add_log("not fitted yet: choose a preset and a budget, then Fit");
            return;
        }
        try {
            PrepareLog log([this](const std::string& l) { add_log(l); });
            log.set_stage_sink(
                [this](const std::string& n, double b, double e) { prep_stage(n, b, e); });
            m_engine = open_fitted(project, log);
            std::lock_guard<std::mutex> lk(m_mutex);
            m_status.snap = m_engine->snapshot();
            m_status.state = State::Ready;
        } catch (...) {
            set_state(State::Failed);
            throw;
        }
        add_log("loaded checkpoint at step " + std::to_string(m_engine->snapshot().step));
    });
}

void FitWorker::close() {
    stop();
    post("close", [this](FitEngine*, const Project&) {
        m_engine.reset();
        std::lock_guard<std::mutex> lk(m_mutex);
        m_project.reset();
        m_depth.reset();
        m_status = Status{};
    });
}

void FitWorker::start(const FitSettings& settings, bool resume) {
    set_state(State::Preparing);
    begin_prep();  // the budget counts from the click
    post("start fit", [this, settings, resume](FitEngine*, const Project&) {
        if (!m_project) throw Error("no project is open");
        const fs::path dir = fit_dir(*m_project);
        const bool can_resume = resume && FitEngine::has_checkpoint(dir);
        FitSettings s = settings;
        // A fit from scratch takes the default kernel (or the fit.kernel setting); a resumed one
        // keeps its checkpoint's.
        if (!can_resume) {
            s.setup.kernel = FitSetupOptions{}.kernel;
            apply_settings(s.setup.settings, s.setup);
        }
        const bool same_setup = m_engine && s.setup.coc_path == m_settings.setup.coc_path &&
                                s.setup.mask_path == m_settings.setup.mask_path &&
                                s.setup.kernel == m_settings.setup.kernel;
        std::shared_ptr<FitData> data;
        set_state(State::Preparing);
        if (same_setup) {
            data = std::make_shared<FitData>(m_engine->data());
        } else {
            PrepareLog log([this](const std::string& l) { add_log(l); });
            log.set_stage_sink(
                [this](const std::string& n, double b, double e) { prep_stage(n, b, e); });
            data = build_fit_data(*m_project, s.setup, log);
        }
        prep_stage("building the model", 0.92, 1.0);
        // The time budget holds the preparation: the fit gets what is left of it (a tenth at
        // least, so that a preparation longer than the budget still leaves a fit).
        const double prep_s = prep_elapsed(), typed = s.fit.minutes;
        if (typed > 0) {
            s.fit.minutes = std::max(typed - prep_s / 60.0, 0.1 * typed);
            char line[128];
            std::snprintf(line, sizeof line, "preparation took %.0f s of the %.1f-minute budget",
                          prep_s, typed);
            add_log(line);
        }
        std::unique_ptr<FitEngine> engine;
        if (can_resume) {
            // The budget counts from where the checkpoint stopped. Both engines open from the
            // checkpoint without the set-up's alignment and fusions (restoring_options).
            auto probe = std::make_unique<FitEngine>(data, restoring_options(*m_project, s.fit));
            probe->load_checkpoint(dir);
            const FitSnapshot at = probe->snapshot();
            if (s.fit.minutes > 0) s.fit.minutes += at.elapsed_s / 60.0;
            if (s.fit.iters > 0) s.fit.iters += at.step;
            probe.reset();
            engine = std::make_unique<FitEngine>(data, restoring_options(*m_project, s.fit));
            engine->load_checkpoint(dir);
            add_log("resuming from step " + std::to_string(at.step));
        } else {
            engine = std::make_unique<FitEngine>(data, s.fit);
            add_log("fitting from scratch: preset " + s.fit.preset);
        }
        write_fit_settings(*m_project, s, nullptr);
        m_engine = std::move(engine);
        std::lock_guard<std::mutex> lk(m_mutex);
        m_settings = s;
        m_fitting = true;
        m_status.state = State::Fitting;
        m_status.history.clear();
        m_status.prep_s = prep_s;
    });
}

void FitWorker::set_paused(bool paused) {
    std::lock_guard<std::mutex> lk(m_mutex);
    if (!m_fitting) return;
    m_status.state = paused ? State::Paused : State::Fitting;
    m_cv.notify_all();
}

void FitWorker::stop() {
    std::lock_guard<std::mutex> lk(m_mutex);
    if (!m_fitting) return;
    m_jobs.emplace_front("stop fit", [this](FitEngine*, const Project&) { end_fit("stopped"); });
    m_cv.notify_all();
}

void FitWorker::end_fit(const std::string& why) {
    if (!m_engine) return;
    {
        std::lock_guard<std::mutex> lk(m_mutex);
        if (!m_fitting) return;
        m_fitting = false;
    }
    m_engine->request_stop();
    m_engine->save_checkpoint(fit_dir(*m_project));
    const FitSnapshot s = m_engine->snapshot();
    write_fit_settings(*m_project, m_settings, &s);
    add_log(why + " at step " + std::to_string(s.step) + ", checkpoint saved");
    // A stopped engine refuses more steps; keep the fitted state for rendering.
    std::lock_guard<std::mutex> lk(m_mutex);
    m_has_checkpoint = true;
    m_status.snap = s;
    m_status.state = State::Ready;
}

void FitWorker::fit_step() {
    m_engine->step();
    const FitSnapshot s = m_engine->snapshot();
    if (m_engine->maybe_checkpoint(fit_dir(*m_project))) {
        std::lock_guard<std::mutex> lk(m_mutex);
        m_has_checkpoint = true;
    }
    {
        std::lock_guard<std::mutex> lk(m_mutex);
        m_status.snap = s;
        auto& h = m_status.history;
        h.push_back(s);
        if (h.size() > 4000) {  // keep every other old entry: bounded, whole curve kept
            std::vector<FitSnapshot> thin;
            for (size_t i = 0; i < h.size(); i += 2) thin.push_back(h[i]);
            h.swap(thin);
        }
    }
    if (m_engine->done()) end_fit("budget used");
}

std::future<std::optional<FitWorker::ViewFrame>> FitWorker::frame_async(int t) {
    std::promise<std::optional<ViewFrame>> p;
    auto f = p.get_future();
    std::lock_guard<std::mutex> lk(m_mutex);
    if (m_quit) {
        p.set_value(std::nullopt);
        return f;
    }
    m_frame_jobs.emplace_back(t, std::move(p));
    m_cv.notify_all();
    return f;
}

std::optional<FitWorker::ViewFrame> FitWorker::render_view_frame(int t) {
    if (!m_engine) return std::nullopt;
    try {
        ViewFrame v;
        v.t = t;
        v.maps = frame_maps(*m_engine, t);
        v.radius = tensor_to_image(m_engine->data().radius[t].contiguous());
        v.confidence = confidence_image(*m_engine, t);
        v.atlas_version = m_engine->snapshot().atlas_version;
        return v;
    } catch (const std::exception& e) {
        std::lock_guard<std::mutex> l2(m_mutex);
        m_status.error = std::string("render frame: ") + e.what();
        return std::nullopt;
    }
}

void FitWorker::request_atlases() {
    std::lock_guard<std::mutex> lk(m_mutex);
    m_atlas_request = true;
    m_cv.notify_all();
}

std::optional<FitWorker::Atlases> FitWorker::take_atlases() {
    std::lock_guard<std::mutex> lk(m_mutex);
    auto r = std::move(m_atlas_result);
    m_atlas_result.reset();
    return r;
}

void FitWorker::request_depth(bool rebuild) {
    post("depth", [this, rebuild](FitEngine* engine, const Project& p) {
        if (!engine) throw Error("fit the project first: the depth comes from the fitted layers");
        const int64_t step = engine->snapshot().step;
        if (!rebuild && m_depth && m_depth_step == step) return;
        const fs::path dir = depth_dir(p.dir);
        std::shared_ptr<DepthModel> d;
        if (!rebuild && DepthModel::exists(dir)) {
            try {
                auto loaded = std::make_shared<DepthModel>(DepthModel::load(dir));
                if (loaded->fit_step == step) d = loaded;  // fitted on this very checkpoint
            } catch (const std::exception& e) {
                add_log(std::string("depth/ unreadable, fitting it again: ") + e.what());
            }
        }
        if (!d) {
            add_log("fitting depth to the radius maps ...");
            d = std::make_shared<DepthModel>(build_depth(*engine));
            d->fit_step = step;
            d->save(dir);
            char b[96];
            std::snprintf(b, sizeof b, "depth fitted: rms %.2f px", d->rms_px);
            add_log(b);
        }
        std::lock_guard<std::mutex> lk(m_mutex);
        m_depth = d;
        m_depth_step = step;
    });
}

void FitWorker::loop() {
    while (true) {
        std::unique_lock<std::mutex> lk(m_mutex);
        m_cv.wait(lk, [&] {
            return m_quit || !m_jobs.empty() || !m_frame_jobs.empty() || m_atlas_request ||
                   (m_fitting && m_status.state == State::Fitting);
        });
        if (m_quit) break;
        if (!m_jobs.empty()) {
            auto job = std::move(m_jobs.front());
            m_jobs.pop_front();
            lk.unlock();
            run_job(job.first, job.second);
            continue;
        }
        if (!m_frame_jobs.empty()) {
            auto job = std::move(m_frame_jobs.front());
            m_frame_jobs.pop_front();
            lk.unlock();
            job.second.set_value(render_view_frame(job.first));
            continue;
        }
        if (m_atlas_request) {
            m_atlas_request = false;
            lk.unlock();
            if (!m_engine || !m_engine->has_atlas()) continue;
            Atlases a;
            {
                std::lock_guard<std::mutex> ml(m_engine->model_mutex());
                torch::NoGradGuard g;
                a.bg = tensor_to_image(m_engine->model().atlas_bg().clamp_min(0).contiguous());
                torch::Tensor fg = m_engine->model().atlas_fg();
                if (fg.defined()) a.fg = tensor_to_image(fg.clamp_min(0).contiguous());
            }
            a.version = m_engine->snapshot().atlas_version;
            std::lock_guard<std::mutex> l2(m_mutex);
            m_atlas_result = std::move(a);
            continue;
        }
        lk.unlock();
        try {
            fit_step();
        } catch (const std::exception& e) {
            {
                std::lock_guard<std::mutex> l2(m_mutex);
                m_fitting = false;
                m_status.state = State::Failed;
                m_status.error = std::string("fit: ") + e.what();
            }
            add_log("error: fit: " + std::string(e.what()));
        }
    }
    // Leaving: a fit in progress keeps its work.
    if (m_fitting && m_engine) {
        try {
            end_fit("closed");
        } catch (...) {
        }
    }
}

}  // namespace refocus
